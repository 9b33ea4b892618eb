"""Camera calibration from views of a checkerboard or ChArUco board (OpenCV), written as the
``camera.yaml`` that ``vslam run --camera`` reads.

The pinhole model is Zhang's method (``cv2.calibrateCamera``: ``k1 k2 p1 p2 k3``); ``fisheye``
is the Kannala-Brandt / equidistant model (``cv2.fisheye.calibrate``: ``k1..k4``). The RMS
reprojection error is over all corners; a view whose own RMS is above ``max(2 * median, 1 px)`` is
reported as an outlier (and dropped, then the calibration is redone, when ``drop_outliers``).

The result is checked (:func:`quality_warnings`): a principal point more than 10 % of the image
size from its centre, extreme distortion terms (a radial model that folds over inside the image,
``|k| > 1``, ``|p| > 0.05``), views that leave part of the image empty (3x3 grid: the empty cells
named, "left edge", "top-right corner" ...) and fewer than 10 views each give a warning, with the
advice to take more views.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from vslam.errors import CalibrationError, DatasetError
from vslam.geometry.camera import PinholeCamera

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Board:
    """A checkerboard of ``cols x rows`` inner corners (ChArUco: ``cols x rows`` squares) of
    ``square`` metres; ``charuco`` names the ArUco dictionary (e.g. ``DICT_5X5_100``)."""

    cols: int
    rows: int
    square: float
    charuco: str | None = None
    marker: float | None = None  # ChArUco marker side in metres (default 0.75 * square)

    def object_points(self) -> np.ndarray:
        """Corner coordinates on the board plane (z = 0), row by row, ``(N, 3)`` metres."""
        n_c, n_r = (self.cols - 1, self.rows - 1) if self.charuco else (self.cols, self.rows)
        grid = np.mgrid[0:n_c, 0:n_r].T.reshape(-1, 2) * self.square
        return np.hstack([grid, np.zeros((len(grid), 1))]).astype(np.float32)

    def charuco_board(self):
        import cv2

        name = self.charuco if self.charuco.startswith("DICT_") else f"DICT_{self.charuco}"
        if not hasattr(cv2.aruco, name):
            raise CalibrationError(f"unknown ArUco dictionary {self.charuco!r} (e.g. DICT_5X5_100)")
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square, self.marker or 0.75 * self.square, d)


def parse_board(spec: str) -> tuple[int, int]:
    """``"9x6"`` -> ``(9, 6)``."""
    try:
        c, r = (int(x) for x in spec.lower().split("x"))
    except ValueError:
        raise CalibrationError(f"--board must be COLSxROWS, e.g. 9x6, got {spec!r}") from None
    if c < 2 or r < 2:
        raise CalibrationError(f"--board needs at least 2x2, got {spec!r}")
    return c, r


@dataclass
class CalibrationResult:
    camera: PinholeCamera
    model: str  # "radtan" or "equidistant"
    rms: float
    view_rms: dict[str, float]
    outliers: list[str]
    no_board: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)  # quality_warnings(), the advice last

    def summary(self) -> str:
        c = self.camera
        lines = [
            f"{len(self.view_rms)} views with the board ({len(self.no_board)} without), model {self.model}",
            f"fx {c.fx:.3f} fy {c.fy:.3f} cx {c.cx:.3f} cy {c.cy:.3f} ({c.width}x{c.height})",
            f"dist {' '.join(f'{d:.6f}' for d in c.dist)}",
            f"RMS reprojection error {self.rms:.4f} px",
            "per-view RMS reprojection error [px]:",
        ]
        for name, err in self.view_rms.items():
            lines.append(f"  {name}: {err:.3f}" + (" (outlier)" if name in self.outliers else ""))
        for name in self.outliers:
            lines.append(f"outlier view: {name} (RMS {self.view_rms[name]:.3f} px)")
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)

    def to_yaml(self) -> str:
        c = self.camera
        return (
            f"# written by vslam calibrate: RMS reprojection error {self.rms:.4f} px over {len(self.view_rms)} views\n"
            f"model: {self.model}\nfx: {c.fx!r}\nfy: {c.fy!r}\ncx: {c.cx!r}\ncy: {c.cy!r}\n"
            f"width: {c.width}\nheight: {c.height}\ndist: [{', '.join(repr(float(d)) for d in c.dist)}]\n"
        )


def read_source(source: str | Path, every: int = 1) -> Iterator[tuple[str, np.ndarray]]:
    """``(name, grayscale image)`` of an image folder or the frames of a video (every N-th)."""
    import cv2

    from vslam.datasets.base import list_images, load_image

    source = Path(source)
    if source.is_dir():
        files = list_images(source)
        if not files:
            raise DatasetError(f"{source}: no image files")
        for f in files[::max(1, every)]:
            yield f.name, load_image(f, grayscale=True)
        return
    if not source.is_file():
        raise DatasetError(f"{source}: no such image folder or video")
    cap = cv2.VideoCapture(str(source))
    if not cap.isOpened():
        raise DatasetError(f"{source}: OpenCV cannot open this video")
    try:
        i = 0
        while True:
            ok, img = cap.read()
            if not ok:
                break
            if i % max(1, every) == 0:
                yield f"frame {i}", cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img
            i += 1
    finally:
        cap.release()


def detect_board(gray: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray] | None:
    """``(object points (N, 3), image points (N, 2))`` of the board in one image, or None."""
    import cv2

    if board.charuco:
        det = cv2.aruco.CharucoDetector(board.charuco_board())
        corners, ids, _mc, _mi = det.detectBoard(gray)
        if ids is None or len(ids) < 6:
            return None
        obj = board.object_points()[ids.ravel()]
        return obj, corners.reshape(-1, 2).astype(np.float32)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    ok, corners = cv2.findChessboardCorners(gray, (board.cols, board.rows), flags=flags)
    if not ok:
        return None
    corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4))
    return board.object_points(), corners.reshape(-1, 2)


def _calibrate(obj, img, size, fisheye: bool):
    import cv2

    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-9)
    if fisheye:
        flags = cv2.fisheye.CALIB_RECOMPUTE_EXTRINSIC | cv2.fisheye.CALIB_FIX_SKEW
        rms, K, D, rvecs, tvecs = cv2.fisheye.calibrate(
            [o.reshape(-1, 1, 3).astype(np.float64) for o in obj], [i.reshape(-1, 1, 2).astype(np.float64) for i in img],
            size, None, None, flags=flags, criteria=crit)
    else:
        rms, K, D, rvecs, tvecs = cv2.calibrateCamera(obj, img, size, None, None, criteria=crit)
    errs = []
    for o, i, r, t in zip(obj, img, rvecs, tvecs):
        if fisheye:
            proj = cv2.fisheye.projectPoints(o.reshape(-1, 1, 3).astype(np.float64), r, t, K, D)[0]
        else:
            proj = cv2.projectPoints(o, r, t, K, D)[0]
        errs.append(float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - i) ** 2, axis=1)))))
    return float(rms), K, np.asarray(D, float).ravel(), errs


def calibrate_views(views, board: Board, fisheye: bool = False, drop_outliers: bool = True,
                    min_views: int = 4) -> CalibrationResult:
    """Calibrate from ``(name, grayscale image)`` views (see the module docstring)."""
    names, obj, img, no_board, size = [], [], [], [], None
    for name, gray in views:
        if size is None:
            size = (gray.shape[1], gray.shape[0])
        elif (gray.shape[1], gray.shape[0]) != size:
            raise CalibrationError(f"{name}: image is {gray.shape[1]}x{gray.shape[0]}, the first was {size[0]}x{size[1]}")
        found = detect_board(gray, board)
        if found is None:
            no_board.append(name)
            continue
        names.append(name)
        obj.append(found[0])
        img.append(found[1])
    if len(names) < min_views:
        raise CalibrationError(
            f"the board ({board.cols}x{board.rows} {'squares' if board.charuco else 'inner corners'}) was found "
            f"in {len(names)} views, at least {min_views} are needed; check --board (inner corners for a checkerboard)"
        )
    rms, K, D, errs = _calibrate(obj, img, size, fisheye)
    median = float(np.median(errs))
    outliers = [n for n, e in zip(names, errs) if e > max(2.0 * median, 1.0)]
    view_rms = dict(zip(names, errs))
    if outliers and drop_outliers and len(names) - len(outliers) >= min_views:
        keep = [k for k, n in enumerate(names) if n not in outliers]
        rms, K, D, errs2 = _calibrate([obj[k] for k in keep], [img[k] for k in keep], size, fisheye)
        view_rms.update({names[k]: e for k, e in zip(keep, errs2)})
        log.info("dropped %d outlier views and recalibrated", len(outliers))
    model = "equidistant" if fisheye else "radtan"
    dist = tuple(float(x) for x in (D[:4] if fisheye else D[:5]))
    cam = PinholeCamera(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), size[0], size[1],
                        dist if fisheye else tuple(list(dist) + [0.0] * (5 - len(dist))))
    dropped = bool(outliers and drop_outliers and len(names) - len(outliers) >= min_views)
    used = [i for n, i in zip(names, img) if not (dropped and n in outliers)]
    warnings = quality_warnings(cam, model, used, size)
    for w in warnings:
        log.info("calibration: %s", w)
    return CalibrationResult(cam, model, rms, view_rms, outliers, no_board, warnings)


# ============================================================================ quality checks
#: a principal point further than this fraction of the image size from the centre is suspicious
MAX_CENTRE_OFFSET = 0.10
#: fewer views than this give a warning
MIN_GOOD_VIEWS = 10
#: a grid cell counts as covered when the views' boards cover this fraction of it
MIN_CELL_COVER = 0.25
CELL_NAMES = (("top-left corner", "top edge", "top-right corner"),
              ("left edge", "centre", "right edge"),
              ("bottom-left corner", "bottom edge", "bottom-right corner"))


def quality_warnings(camera: PinholeCamera, model: str, corners: list[np.ndarray],
                     size: tuple[int, int]) -> list[str]:
    """What looks wrong with a calibration from the image points ``corners`` (one ``(N, 2)`` array
    per view) of ``size`` ``(width, height)`` images (see the module docstring); the last entry,
    when there is any, says to take more views."""
    out = []
    w, h = size
    dx, dy = (camera.cx - (w - 1) / 2) / w, (camera.cy - (h - 1) / 2) / h
    if max(abs(dx), abs(dy)) > MAX_CENTRE_OFFSET:
        out.append(f"principal point ({camera.cx:.1f}, {camera.cy:.1f}) is {100 * abs(dx):.0f} % of the width and "
                   f"{100 * abs(dy):.0f} % of the height from the image centre (more than "
                   f"{100 * MAX_CENTRE_OFFSET:.0f} % is rare for a real lens)")
    extreme = _extreme_distortion(camera, model)
    if extreme:
        out.append(f"distortion terms are extreme ({extreme})")
    fraction, missing = view_coverage(corners, size)
    if missing:
        out.append(f"the views cover {100 * fraction:.0f} % of the image; no board seen in the "
                   + ", ".join(missing))
    if len(corners) < MIN_GOOD_VIEWS:
        out.append(f"only {len(corners)} views with the board ({MIN_GOOD_VIEWS} or more recommended)")
    if out:
        where = f", with the board in the {' / '.join(missing)}," if missing else ""
        out.append(f"take more views{where} at several distances and tilts (15-30 in all), and calibrate again")
    return out


def _extreme_distortion(camera: PinholeCamera, model: str) -> str:
    """Why the distortion terms are extreme ("" when they are not): a term beyond what lenses have,
    or a radial model that folds over (stops increasing) inside the image."""
    d = np.asarray(camera.dist, float)
    names = ("k1", "k2", "k3", "k4") if model == "equidistant" else ("k1", "k2", "p1", "p2", "k3")
    big = [f"{n} {v:.3g}" for n, v in zip(names, d)
           if abs(v) > (0.05 if n in ("p1", "p2") else 1.0)]
    fold = ""
    if model != "equidistant" and len(d) >= 5:
        k1, k2, k3 = d[0], d[1], d[4]
        corners = np.array([[0, 0], [camera.width, 0], [0, camera.height], [camera.width, camera.height]], float)
        r_max = float(np.max(np.hypot((corners[:, 0] - camera.cx) / camera.fx, (corners[:, 1] - camera.cy) / camera.fy)))
        r = np.linspace(0.0, r_max, 200)
        slope = 1 + 3 * k1 * r ** 2 + 5 * k2 * r ** 4 + 7 * k3 * r ** 6  # d/dr of r (1 + k1 r^2 + k2 r^4 + k3 r^6)
        if np.any(slope <= 0):
            fold = f"the radial model folds over at {100 * r[np.argmax(slope <= 0)] / r_max:.0f} % of the corner radius"
    return "; ".join(p for p in (", ".join(big), fold) if p)


def view_coverage(corners: list[np.ndarray], size: tuple[int, int]) -> tuple[float, list[str]]:
    """``(fraction of the image inside some view's board, names of the 3x3 grid cells covered less
    than MIN_CELL_COVER)``; a view's board is the convex hull of its corners."""
    import cv2

    w, h = size
    step = max(1, int(max(w, h) // 160))  # a coarse mask is enough
    mw, mh = -(-w // step), -(-h // step)
    mask = np.zeros((mh, mw), np.uint8)
    for pts in corners:
        p = np.asarray(pts, float).reshape(-1, 2) / step
        if len(p) >= 3:
            cv2.fillConvexPoly(mask, cv2.convexHull(np.round(p).astype(np.int32)), 1)
    missing = []
    for i in range(3):
        for j in range(3):
            cell = mask[i * mh // 3:(i + 1) * mh // 3, j * mw // 3:(j + 1) * mw // 3]
            if cell.size and cell.mean() < MIN_CELL_COVER:
                missing.append(CELL_NAMES[i][j])
    return float(mask.mean()), missing


def calibrate_source(source: str | Path, board: Board, output: str | Path | None = None, fisheye: bool = False,
                     every: int = 1) -> CalibrationResult:
    """Calibrate from an image folder or a video and write ``output`` (vslam ``camera.yaml``),
    atomically; ``output`` may not be the video or one of the images (refused before the work)."""
    from vslam.outputs import IMAGE_SUFFIXES, atomic_write_text, check_output_file, refuse_inputs, same_path

    out = Path(output) if output is not None else None
    if out is not None:
        refuse_inputs(out, (source,), "calibration")
        if Path(source).is_dir() and same_path(out.parent, source) and out.suffix.lower() in IMAGE_SUFFIXES:
            raise CalibrationError(f"{out}: is one of the calibration images in {source}; write the calibration "
                                   "to a .yaml file")
        if not out.parent.is_dir():
            raise CalibrationError(f"{out}: folder {out.parent} does not exist")
        check_output_file(out, "calibration")
    result = calibrate_views(read_source(source, every), board, fisheye=fisheye)
    if out is not None:
        atomic_write_text(out, result.to_yaml())
    return result
