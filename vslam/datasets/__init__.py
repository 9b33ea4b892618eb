"""Dataset readers: one module per format, all yielding :class:`vslam.datasets.frame.Frame`.

Use :func:`open_dataset` (format detected from the path, or forced with ``kind``)::

    ds = open_dataset("../shared/data/tum_fr3_cabinet_keyframes58", sensor="rgbd")
    for frame in ds:            # images are decoded lazily, one frame at a time
        ...
    gt = ds.ground_truth()      # Trajectory at the frame timestamps, or None
"""
from vslam.datasets.base import SENSORS, Dataset
from vslam.datasets.detect import KINDS, detect_kind, open_dataset
from vslam.datasets.frame import Frame

__all__ = ["Dataset", "Frame", "KINDS", "SENSORS", "detect_kind", "open_dataset"]
