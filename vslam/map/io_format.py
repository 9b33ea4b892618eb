"""The constants of the map format (version 1, documented in ``FORMAT.md``): file names, the
storage kind and shape of every KeyFrame field, the MapPointStore columns, the Map attributes."""
from __future__ import annotations

FORMAT_NAME = "vslam-map"
FORMAT_VERSION = 2  # 2: the segment table (map.json "segments"); version 1 maps still load
READABLE_VERSIONS = (1, 2)
MAP_DIRNAME = "map"
MANIFEST_FILE = "map.json"
KEYFRAMES_FILE = "keyframes.npz"
POINTS_FILE = "points.npz"
COVISIBILITY_FILE = "covisibility.npz"
DATABASE_FILE = "database.npz"

# Storage kind of each KeyFrame field in format version 1 (documented in FORMAT.md):
#   scalar    one value per keyframe -> array (K,)
#   stacked   one fixed-shape array per keyframe (or None) -> stacked (K_present, ...)
#   keypoint  one (N_k, ...) array per keyframe (or None) -> concatenated (sum N_k present, ...)
#   dict      a dict of JSON values / NumPy arrays -> (K,) JSON strings + one member per array
KEYFRAME_FIELD_KINDS: dict[str, str] = {
    "id": "scalar",
    "frame_index": "scalar",
    "timestamp": "scalar",
    "T_world_cam": "stacked",
    "uv": "keypoint",
    "uv_undist": "keypoint",
    "descriptors": "keypoint",
    "octave": "keypoint",
    "depth": "keypoint",
    "point_ids": "keypoint",
    "segment": "scalar",
    "u_right": "keypoint",
    "bad": "scalar",
    "extra": "dict",
}
# Shape of one keyframe's value (stacked) or of one keypoint's value (keypoint), checked on load.
KEYFRAME_FIELD_SHAPES: dict[str, tuple[int, ...]] = {
    "T_world_cam": (4, 4), "uv": (2,), "uv_undist": (2,), "octave": (), "depth": (), "point_ids": (), "u_right": (),
}
KEYPOINT_COUNT_FIELD = "uv"  # its length is the keyframe's keypoint count N_k
# MapPointStore columns documented in format version 1 (any array column is saved generically).
POINT_COLUMNS = ("position", "normal", "min_distance", "max_distance", "found", "visible", "n_obs",
                 "first_kf", "last_seen_kf", "alive", "color", "descriptor")
# Map attributes handled explicitly (gravity_aligned: written to map_attributes as a checked bool);
# any other scalar attribute is saved in map.json.
MAP_STRUCTURES = ("keyframes", "points", "covisibility", "segments", "gravity_aligned")

KINDS = ("scalar", "stacked", "keypoint", "dict")
JSON_SCALARS = (bool, int, float, str, type(None))
