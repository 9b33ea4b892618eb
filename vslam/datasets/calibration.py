"""Camera calibration files in the formats other tools write: ``read_camera_file`` detects the format.

Formats (detected from the content, first match wins):

* ``kitti``: a KITTI ``calib.txt`` (``P0:`` 12 numbers, optional ``P1:`` for the right camera);
  the image size comes from the images.
* ``kalibr``: a Kalibr ``camchain.yaml`` (``cam0: {camera_model, intrinsics, distortion_model,
  distortion_coeffs, resolution}``; ``pinhole`` with ``radtan`` or ``equidistant``; a ``cam1`` with
  ``T_cn_cnm1`` makes a stereo rig).
* ``orbslam3``: ORB-SLAM3 v1.0 settings (``Camera.type``, ``Camera1.fx`` ..., ``Camera2.*`` and
  ``Stereo.T_c1_c2`` for a stereo rig, ``Stereo.b`` for a rectified one, ``RGBD.DepthMapFactor``).
* ``ros``: a ROS ``camera_info`` YAML (``camera_matrix``, ``distortion_model``,
  ``distortion_coefficients``, ``image_width``, ``image_height``).
* ``opencv``: OpenCV FileStorage YAML or XML as ``calibrateCamera`` samples write it
  (``camera_matrix``, ``distortion_coefficients``, ``image_width``, ``image_height``).
* ``euroc``: a EuRoC/ASL ``sensor.yaml`` (``intrinsics``, ``resolution``, ``T_BS``).
* ``orbslam2``: ORB-SLAM2 settings (``Camera.fx`` ..., ``Camera.bf``, ``DepthMapFactor``).
* ``vslam``: the project's small ``camera.yaml`` (``fx fy cx cy width height`` + optional ``dist``,
  ``model``, ``baseline``, ``depth_scale``, ``fps``); see :func:`vslam.datasets.base.read_camera_yaml`.

A TUM preset can be named instead of a file: ``fr1``, ``fr2``, ``fr3`` (or ``freiburg1`` ...).

Lens models: ``radtan`` (OpenCV plumb bob ``k1 k2 p1 p2 k3``) stays on the camera; the pipeline
undistorts keypoints. ``equidistant`` (Kannala-Brandt ``k1..k4``, OpenCV ``cv2.fisheye``) and raw
(unrectified) stereo rigs are turned into an ideal pinhole camera by remapping the images
(:class:`Rectifier`), so every later stage sees a pinhole camera.
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vslam.datasets.calib_checks import check_camera, check_extras, check_file_size, number, numbers
from vslam.datasets.camera_yaml import load_yaml as _load_yaml, pixels, read_camera_yaml
from vslam.errors import CalibrationError
from vslam.geometry.camera import PinholeCamera
from vslam.geometry.lie import inv_se3

log = logging.getLogger(__name__)

MODELS = ("radtan", "equidistant")
_MODEL_ALIASES = {
    "radtan": "radtan", "radial-tangential": "radtan", "plumb_bob": "radtan", "pinhole": "radtan",
    "rational_polynomial": "radtan", "none": "radtan", "equidistant": "equidistant", "fisheye": "equidistant",
    "kannala_brandt": "equidistant", "kannalabrandt8": "equidistant", "kb4": "equidistant",
}
FORMAT_NAMES = {
    "vslam": "vslam camera.yaml", "opencv": "OpenCV FileStorage calibration", "orbslam2": "ORB-SLAM2 settings",
    "orbslam3": "ORB-SLAM3 v1.0 settings", "kalibr": "Kalibr camchain", "ros": "ROS camera_info",
    "kitti": "KITTI calib.txt", "euroc": "EuRoC sensor.yaml", "tum-preset": "TUM preset",
}
_PRESET_RE = re.compile(r"^(?:tum[:_-]?)?(?:freiburg|fr)_?([123])$", re.IGNORECASE)


@dataclass(frozen=True)
class Calibration:
    """A calibration as read from a file: the (possibly distorted, possibly fisheye) camera,
    an optional second camera of a stereo rig and its pose, and extras (``fps``, ``depth_scale``).

    ``T_right_left`` maps left-camera points into the right camera (``X_r = T X_l``).
    """

    camera: PinholeCamera
    format: str
    model: str = "radtan"
    right: PinholeCamera | None = None
    T_right_left: np.ndarray | None = None
    extras: dict = field(default_factory=dict)
    source: str = ""

    @property
    def needs_remap(self) -> bool:
        """Whether images must be remapped to give the pipeline a pinhole camera (fisheye or a
        stereo rig that is not rectified already)."""
        return self.model == "equidistant" or self.right is not None

    def describe(self) -> str:
        c = self.camera
        rig = f", stereo rig (baseline {np.linalg.norm(self.T_right_left[:3, 3]):.4f} m)" if self.right is not None else ""
        return (f"{FORMAT_NAMES.get(self.format, self.format)} {self.source}: fx {c.fx:.2f} fy {c.fy:.2f} "
                f"cx {c.cx:.2f} cy {c.cy:.2f} {c.width}x{c.height}, {self.model}{rig}")


def _model(name, where: str) -> str:
    key = str(name).strip().lower().replace(" ", "_")
    if key not in _MODEL_ALIASES:
        raise CalibrationError(
            f"{where}: distortion model {name!r} is not supported; use radtan (plumb_bob) or equidistant (fisheye)"
        )
    return _MODEL_ALIASES[key]


class _Fields:
    """Typed access to a parsed file with errors that name the detected format and the missing key."""

    def __init__(self, data: dict, path: Path, fmt: str) -> None:
        self.data, self.path, self.fmt = data, path, fmt

    def _missing(self, key: str) -> CalibrationError:
        return CalibrationError(f"{self.path}: detected format: {FORMAT_NAMES[self.fmt]}, but field '{key}' is missing")

    def get(self, key: str, default=...):
        node = self.data
        for part in key.split("/"):
            if not isinstance(node, dict) or part not in node or node[part] is None:
                if default is ...:
                    raise self._missing(key)
                return default
            node = node[part]
        return node

    def number(self, key: str, default=...) -> float:
        v = self.get(key, default)
        if v is None:
            return v
        return number(v, key, f"{self.path}: {FORMAT_NAMES[self.fmt]}")  # not a boolean, not text, finite

    def array(self, key: str, size: int | tuple[int, ...] | None = None, default=...) -> np.ndarray | None:
        v = self.get(key, default)
        if v is None:
            return None
        if isinstance(v, dict):  # OpenCV matrix {rows, cols, dt, data} or ROS {rows, cols, data}
            if "data" not in v:
                raise CalibrationError(f"{self.path}: {FORMAT_NAMES[self.fmt]}: '{key}' has no 'data' list")
            v = v["data"]
        if not isinstance(v, (list, tuple)):
            raise CalibrationError(f"{self.path}: {FORMAT_NAMES[self.fmt]}: '{key}' is not a list of numbers")
        a = np.asarray(numbers(v, key, f"{self.path}: {FORMAT_NAMES[self.fmt]}"), dtype=float)
        sizes = (size,) if isinstance(size, int) else size
        if sizes is not None and a.size not in sizes:
            raise CalibrationError(
                f"{self.path}: {FORMAT_NAMES[self.fmt]}: '{key}' needs {' or '.join(map(str, sizes))} numbers, got {a.size}"
            )
        return a


def _dist5(d: np.ndarray | list | None) -> tuple[float, ...]:
    d = [] if d is None else [float(x) for x in d][:5]
    return tuple(d + [0.0] * (5 - len(d)))


def _camera(fx, fy, cx, cy, w, h, dist, model: str, where: str, baseline=None) -> PinholeCamera:
    """The camera of a calibration file, its numbers checked (:func:`calib_checks.check_camera`)."""
    if fx <= 0 or fy <= 0:
        raise CalibrationError(f"{where}: focal lengths must be positive (fx={fx}, fy={fy})")
    if w is None or h is None or w <= 0 or h <= 0:
        raise CalibrationError(f"{where}: the image size is unknown; add width and height")
    w, h = pixels(w, "width", where), pixels(h, "height", where)
    d = [] if dist is None else [float(x) for x in dist]
    if model == "equidistant":
        if len(d) < 4:
            d = d + [0.0] * (4 - len(d))
        dist_t = tuple(d[:4])
    else:
        if len(d) > 5:
            extra = np.asarray(d[5:])
            if np.any(extra != 0):
                raise CalibrationError(f"{where}: only 5 distortion coefficients (k1 k2 p1 p2 k3) are supported, got {len(d)}")
        dist_t = _dist5(d)
    return check_camera(PinholeCamera(float(fx), float(fy), float(cx), float(cy), w, h, dist_t, baseline), where)


def _size(f: _Fields, wkey: str, hkey: str, image_size) -> tuple[float | None, float | None]:
    w, h = f.number(wkey, None), f.number(hkey, None)
    if (w is None or h is None) and image_size is not None:
        return image_size
    if w is None:
        raise f._missing(wkey)
    if h is None:
        raise f._missing(hkey)
    return w, h


def _rigid(T: np.ndarray, where: str) -> np.ndarray:
    T = np.asarray(T, float).reshape(-1)
    if T.size == 12:
        T = np.concatenate([T, [0, 0, 0, 1]])
    T = T.reshape(4, 4)
    R = T[:3, :3]
    if not np.allclose(T[3], [0, 0, 0, 1]) or not np.allclose(R @ R.T, np.eye(3), atol=1e-4):
        raise CalibrationError(f"{where}: the stereo extrinsics are not a rigid transform")
    return T


def _rectified_pair(T_right_left: np.ndarray, left: PinholeCamera, right: PinholeCamera) -> bool:
    """True when the rig is already rectified: same K, no distortion, pure +x baseline."""
    return (
        np.allclose(T_right_left[:3, :3], np.eye(3), atol=1e-6) and abs(T_right_left[1, 3]) < 1e-6
        and abs(T_right_left[2, 3]) < 1e-6 and T_right_left[0, 3] < 0 and not left.is_distorted
        and not right.is_distorted and np.allclose(left.K, right.K)
    )


def _finish_stereo(cal: Calibration) -> Calibration:
    """A rig that is rectified already becomes a camera with a baseline (no remap)."""
    if cal.right is None or cal.model != "radtan" or not _rectified_pair(cal.T_right_left, cal.camera, cal.right):
        return cal
    c = cal.camera
    cam = PinholeCamera(c.fx, c.fy, c.cx, c.cy, c.width, c.height, c.dist, float(-cal.T_right_left[0, 3]))
    return Calibration(cam, cal.format, cal.model, None, None, cal.extras, cal.source)


# -- format readers ---------------------------------------------------------------------------
def _read_kalibr(f: _Fields, image_size) -> Calibration:
    cams = []
    for name in ("cam0", "cam1"):
        if name not in f.data:
            continue
        model = str(f.get(f"{name}/camera_model", "pinhole"))
        if model != "pinhole":
            raise CalibrationError(f"{f.path}: Kalibr camera model {model!r} of {name} is not supported (use pinhole)")
        fx, fy, cx, cy = f.array(f"{name}/intrinsics", 4)
        w, h = f.array(f"{name}/resolution", 2)
        dmodel = _model(f.get(f"{name}/distortion_model", "radtan"), str(f.path))
        dist = f.array(f"{name}/distortion_coeffs", (0, 4, 5), [])
        cams.append((_camera(fx, fy, cx, cy, w, h, dist, dmodel, str(f.path)), dmodel))
    (left, model), right = cams[0], None
    T = None
    if len(cams) > 1:
        right, model_r = cams[1]
        if model_r != model:
            raise CalibrationError(f"{f.path}: cam0 is {model} but cam1 is {model_r}; both must use one model")
        T = _rigid(f.array("cam1/T_cn_cnm1", (12, 16)), str(f.path))
    return _finish_stereo(Calibration(left, "kalibr", model, right, T, {}, str(f.path)))


def _read_orbslam3(f: _Fields, image_size) -> Calibration:
    ctype = str(f.get("Camera.type", "PinHole")).strip().strip('"')
    model = {"pinhole": "radtan", "rectified": "radtan", "kannalabrandt8": "equidistant"}.get(ctype.lower())
    if model is None:
        raise CalibrationError(f"{f.path}: ORB-SLAM3 Camera.type {ctype!r} is not supported (PinHole, Rectified, KannalaBrandt8)")
    w, h = _size(f, "Camera.width", "Camera.height", image_size)

    def cam(i: int) -> PinholeCamera:
        k = f"Camera{i}."
        fx, fy, cx, cy = (f.number(k + n) for n in ("fx", "fy", "cx", "cy"))
        if model == "equidistant":
            dist = [f.number(k + n, 0.0) for n in ("k1", "k2", "k3", "k4")]
        else:
            dist = [f.number(k + n, 0.0) for n in ("k1", "k2", "p1", "p2", "k3")]
        return _camera(fx, fy, cx, cy, w, h, dist, model, str(f.path))

    left = cam(1)
    extras = {}
    if "Camera.fps" in f.data:
        extras["fps"] = f.number("Camera.fps")
    if "RGBD.DepthMapFactor" in f.data:
        extras["depth_scale"] = f.number("RGBD.DepthMapFactor")
    if ctype.lower() == "rectified" and "Stereo.b" in f.data:
        left = check_camera(PinholeCamera(left.fx, left.fy, left.cx, left.cy, left.width, left.height, left.dist,
                                          f.number("Stereo.b")), str(f.path))
        return Calibration(left, "orbslam3", model, extras=extras, source=str(f.path))
    if "Camera2.fx" in f.data:
        T_c1_c2 = _rigid(f.array("Stereo.T_c1_c2", (12, 16)), str(f.path))
        cal = Calibration(left, "orbslam3", model, cam(2), inv_se3(T_c1_c2), extras, str(f.path))
        return _finish_stereo(cal)
    return Calibration(left, "orbslam3", model, extras=extras, source=str(f.path))


def _read_ros(f: _Fields, image_size) -> Calibration:
    K = f.array("camera_matrix", 9).reshape(3, 3)
    w, h = _size(f, "image_width", "image_height", image_size)
    model = _model(f.get("distortion_model", "plumb_bob"), str(f.path))
    dist = f.array("distortion_coefficients", None, [])
    return Calibration(_camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], w, h, dist, model, str(f.path)), "ros", model,
                       source=str(f.path))


def _read_opencv(f: _Fields, image_size) -> Calibration:
    K = f.array("camera_matrix", 9).reshape(3, 3)
    w, h = _size(f, "image_width", "image_height", image_size)
    model = _model(f.get("distortion_model", f.get("model", "fisheye" if f.get("fisheye", 0) else "radtan")), str(f.path))
    dist = f.array("distortion_coefficients", None, [])
    return Calibration(_camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], w, h, dist, model, str(f.path)), "opencv", model,
                       source=str(f.path))


def _read_euroc(f: _Fields, image_size) -> Calibration:
    fx, fy, cx, cy = f.array("intrinsics", 4)
    w, h = f.array("resolution", 2)
    model = _model(f.get("distortion_model", "radtan"), str(f.path))
    dist = f.array("distortion_coefficients", (0, 4, 5), [])
    extras = {"fps": f.number("rate_hz")} if "rate_hz" in f.data else {}
    return Calibration(_camera(fx, fy, cx, cy, w, h, dist, model, str(f.path)), "euroc", model, extras=extras,
                       source=str(f.path))


def _read_vslam(path: Path, data: dict, image_size, fmt: str) -> Calibration:
    model = _model(data.get("model", "radtan"), str(path))
    if model == "equidistant":
        f = _Fields(data, path, fmt)
        dist = f.array("dist", (0, 4), [])
        w, h = _size(f, "width", "height", image_size)
        cam = _camera(f.number("fx"), f.number("fy"), f.number("cx"), f.number("cy"), w, h, dist, model, str(path))
        extras = {k: f.number(k) for k in ("fps", "depth_scale", "balance") if k in data}
        if not 0.0 <= extras.get("balance", 0.0) <= 1.0:
            raise CalibrationError(f"{path}: balance must be in [0, 1] (0: only valid pixels, 1: the whole field of view)")
        return Calibration(cam, fmt, model, extras=check_extras(extras, str(path)), source=str(path))
    try:
        cam, extras = read_camera_yaml(path, image_size)
    except CalibrationError as exc:
        msg = str(exc)
        if fmt == "orbslam2" and "lacks '" in msg:
            key = msg.split("lacks '")[1].split("'")[0]
            key = key if key in ("depth_scale", "baseline") else f"Camera.{key}"
            raise CalibrationError(f"{path}: detected format: {FORMAT_NAMES[fmt]}, but field '{key}' is missing") from None
        raise
    return Calibration(cam, fmt, model, extras=extras, source=str(path))


def _read_kitti(path: Path, image_size) -> Calibration:
    from vslam.datasets.kitti import read_kitti_calib

    P = read_kitti_calib(path)
    if image_size is None:
        raise CalibrationError(f"{path}: detected format: KITTI calib.txt, which has no image size; use it beside the images")
    P0 = P["P0"]
    baseline = None
    if "P1" in P and P["P1"][0, 3] < 0:
        baseline = float(-P["P1"][0, 3] / P["P1"][0, 0])
    cam = _camera(P0[0, 0], P0[1, 1], P0[0, 2], P0[1, 2], image_size[0], image_size[1], None, "radtan", str(path),
                  baseline)
    return Calibration(cam, "kitti", source=str(path))


def _read_filestorage(path: Path) -> dict:
    """Top-level nodes of an OpenCV FileStorage file (XML/YAML/JSON) as plain Python values."""
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):  # e.g. an XML file cut off mid-element
        raise CalibrationError(f"{path}: OpenCV cannot parse this file as FileStorage XML/YAML (cut off or "
                               "malformed); fix or re-export it") from None
    try:
        if not fs.isOpened():
            raise CalibrationError(f"{path}: OpenCV cannot parse this file as FileStorage XML/YAML")
        out = {}
        root = fs.root()
        for key in root.keys():
            node = fs.getNode(key)
            if node.isMap() and not node.getNode("data").empty():
                m = node.mat()
                out[key] = {"rows": m.shape[0], "cols": m.shape[1] if m.ndim > 1 else 1, "data": m.ravel().tolist()}
            elif node.isInt():
                out[key] = int(node.real())
            elif node.isReal():
                out[key] = node.real()
            elif node.isString():
                out[key] = node.string()
            elif node.isSeq():
                out[key] = [node.at(i).real() for i in range(node.size())]
        return out
    finally:
        fs.release()


def detect_camera_format(data: dict) -> str | None:
    """The format of a parsed calibration mapping (see the module docstring), or None."""
    keys = {str(k) for k in data}
    if isinstance(data.get("cam0"), dict) and {"intrinsics", "camera_model", "resolution"} & set(data["cam0"]):
        return "kalibr"
    if any(k.startswith("Camera1.") for k in keys):
        return "orbslam3"
    if "camera_matrix" in keys:
        if keys & {"distortion_model", "camera_name", "projection_matrix", "rectification_matrix"}:
            return "ros"
        return "opencv"
    if "intrinsics" in keys and "T_BS" in keys:
        return "euroc"
    if any(k.startswith("Camera.") for k in keys):
        return "orbslam2"
    if "fx" in keys:
        return "vslam"
    return None


def tum_preset_name(spec: str) -> int | None:
    """``fr1`` / ``freiburg2`` / ``tum:fr3`` -> 1, 2, 3; else None."""
    m = _PRESET_RE.match(str(spec).strip())
    return int(m.group(1)) if m else None


def read_camera_file(path: str | Path, image_size: tuple[int, int] | None = None) -> Calibration:
    """Read a calibration in any supported format (detected), or a TUM preset name (``fr1``).

    ``image_size`` ``(W, H)`` fills in the size for formats that may lack it (KITTI, ORB-SLAM2,
    the vslam YAML). Raises :class:`CalibrationError` naming the detected format and the missing field.
    """
    preset = tum_preset_name(str(path))
    if preset is not None and not Path(path).exists():
        from vslam.datasets.tum import TUM_DEPTH_SCALE, TUM_PRESETS

        return Calibration(TUM_PRESETS[preset], "tum-preset", extras={"depth_scale": TUM_DEPTH_SCALE},
                           source=f"freiburg{preset}")
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"{path}: camera file not found (or name a TUM preset: fr1, fr2, fr3)")
    check_file_size(path)  # before any parser sees it
    if path.suffix.lower() == ".txt":
        return _read_kitti(path, image_size)
    if path.suffix.lower() in (".xml", ".json"):
        data = _read_filestorage(path)
    else:
        data = _load_yaml(path)
    fmt = detect_camera_format(data)
    if fmt is None:
        raise CalibrationError(
            f"{path}: unrecognised calibration format (keys: {', '.join(sorted(map(str, data))[:8])}); expected "
            f"vslam camera.yaml (fx ...), OpenCV (camera_matrix ...), ORB-SLAM2/3 (Camera.fx / Camera1.fx), "
            f"Kalibr camchain (cam0: intrinsics), ROS camera_info or KITTI calib.txt"
        )
    if fmt in ("vslam", "orbslam2"):
        return _read_vslam(path, data, image_size, fmt)
    f = _Fields(data, path, fmt)
    reader = {"kalibr": _read_kalibr, "orbslam3": _read_orbslam3, "ros": _read_ros, "opencv": _read_opencv,
              "euroc": _read_euroc}[fmt]
    cal = reader(f, image_size)
    check_extras(cal.extras, str(path))
    return cal


def read_pinhole_calibration(path: str | Path, image_size: tuple[int, int] | None = None,
                             reader: str = "this reader") -> Calibration:
    """A calibration that needs no image remap (radtan, rectified), for readers that do not remap
    images; a fisheye or raw stereo rig raises :class:`CalibrationError`."""
    cal = read_camera_file(path, image_size)
    if cal.needs_remap:
        raise CalibrationError(
            f"{path}: a {cal.model}{' stereo rig' if cal.right is not None else ''} calibration needs image "
            f"remapping, which {reader} does not do; use an image folder, a video or a bag"
        )
    return cal


from vslam.datasets.rectify import Rectifier, frame_camera  # noqa: E402,F401  (re-exported)
