"""Stream a SLAM run to the rerun viewer, or record it to an ``.rrd`` file (optional ``viz`` extra).

``vslam run ... --viz rerun`` opens a viewer (``rerun`` spawns it; the ``rerun`` executable is
looked for next to the running Python first, so it works from a virtual environment that is not
activated: :func:`rerun_executable`), ``--viz rerun:FILE.rrd`` records to a file to open later
with ``rerun FILE.rrd``, ``--viz rerun:rerun+http://HOST:9876/proxy`` connects to a running
viewer. Nothing here needs a display unless a viewer is spawned, and rerun is only imported when
a viewer is created. Smaller recordings: ``image_scale`` (``--viz-scale 0.5`` logs images at half
size) and ``image_every`` (``--viz-every N`` logs the image, features and depth of every N-th
frame only; poses, trajectory and map are logged for every frame).

Where no viewer can open (Linux without ``DISPLAY``/``WAYLAND_DISPLAY``, no ``rerun`` executable,
or its start fails) :class:`ViewerUnavailable` is raised at the start, and ``vslam run`` warns
(suggesting ``--viz rerun:FILE.rrd``) and runs without a viewer; a viewer that fails later is a
warning too, never a failed run.

What is logged per frame (timelines ``frame`` = frame index and ``time`` = timestamp in s):

* ``world/camera``: the camera pose ``T_world_cam`` as a transform (camera -> world);
* ``world/camera/image``: the pinhole model, the image, and ``keypoints`` (the tracked features,
  green when they belong to a map point), ``depth`` for RGB-D;
* ``world/trajectory``: the trajectory so far (one line strip);
* ``world/map_points``: the map, every ``map_every`` frames and on keyframes;
* ``status/inliers`` (a scalar) and ``log`` (tracking state changes).

The world frame is the SLAM world (the first camera: x right, y down, z forward, ``RDF``).

Example::

    viewer = RerunViewer.from_spec("rerun:run.rrd")
    result = run_sequence(system, frames, on_frame=viewer.bind(system))
    viewer.close()
"""
from __future__ import annotations

import logging
import os
import shutil
import sys
from pathlib import Path
from typing import Any, Callable

import numpy as np

from vslam.errors import VslamError

log = logging.getLogger(__name__)


def _import_rerun():
    try:
        import rerun as rr
    except ImportError:
        raise VslamError("--viz rerun needs the rerun SDK: pip install 'vslam[viz]' (rerun-sdk==0.41.0)") from None
    return rr


class ViewerUnavailable(VslamError):
    """No viewer can be opened here (no display, no ``rerun`` executable, or its start failed);
    :func:`vslam.api.run_path` then runs without one, with a warning."""


def no_display_reason(environ: Any = None, platform: str | None = None) -> str | None:
    """Why a spawned viewer window cannot appear (Linux without ``DISPLAY`` or ``WAYLAND_DISPLAY``:
    an SSH session, a container, CI), or None when it can (or this cannot tell)."""
    environ = os.environ if environ is None else environ
    platform = sys.platform if platform is None else platform
    if platform.startswith("linux") and not environ.get("DISPLAY") and not environ.get("WAYLAND_DISPLAY"):
        return "no display: neither DISPLAY nor WAYLAND_DISPLAY is set"
    return None


def rerun_executable() -> str | None:
    """The ``rerun`` viewer executable: beside ``sys.executable`` (a virtual environment's
    ``bin/`` or ``Scripts/``, found even when it is not activated), else on ``PATH``, else None."""
    here = Path(sys.executable).parent
    for name in ("rerun", "rerun.exe"):
        cand = here / name
        if cand.is_file() and os.access(cand, os.X_OK):
            return str(cand)
    return shutil.which("rerun")


def map_points_of(system: Any) -> np.ndarray | None:
    """World positions ``(N, 3)`` of the live map points of ``system``, or None if it has none.

    Uses ``system.map_points_xyz()`` when the system provides it, else the columnar store of
    ``system.map.points`` (``position``, ``alive``).
    """
    if system is None:
        return None
    fn = getattr(system, "map_points_xyz", None)
    if callable(fn):
        xyz = fn()
        return None if xyz is None else np.asarray(xyz, dtype=float).reshape(-1, 3)
    store = getattr(getattr(system, "map", None), "points", None)
    if store is None or not hasattr(store, "position") or not hasattr(store, "alive"):
        return None
    n = len(store)
    return np.asarray(store.position[:n][store.alive[:n]], dtype=float)


def keypoints_of(track_result: Any, system: Any) -> tuple[np.ndarray, np.ndarray | None] | None:
    """``(uv (N, 2), has_map_point (N,) bool or None)`` of the current frame's features, if exposed:
    ``track_result.keypoints`` / ``system.keypoints()`` / the frontend's last observation."""
    uv = getattr(track_result, "keypoints", None)
    if uv is not None:
        return np.asarray(uv, float).reshape(-1, 2), None
    fn = getattr(system, "keypoints", None)
    if callable(fn):
        uv = fn()
        return (np.asarray(uv, float).reshape(-1, 2), None) if uv is not None else None
    obs = getattr(getattr(system, "tracker", None), "prev", None)
    if obs is not None and getattr(obs, "uv", None) is not None:
        ids = getattr(obs, "point_ids", None)
        return np.asarray(obs.uv, float).reshape(-1, 2), (np.asarray(ids) >= 0 if ids is not None else None)
    return None


class RerunViewer:
    """Log frames, features, poses, the trajectory and the map to a rerun recording.

    Args:
        target: ``"spawn"`` (open a viewer), a ``.rrd`` file path (record), or a
            ``rerun+http://...`` URL (connect to a running viewer).
        app_id: the rerun application id.
        system: the :class:`vslam.system.System` (or None); used for map points and features.
        image_scale: downscale images by this factor before logging (smaller recordings).
        map_every: log the map points every N frames (and on every keyframe).
        log_depth: also log RGB-D depth images.
        jpeg_quality: JPEG-compress the images (smaller recordings, 1-100), None for raw pixels.
        image_every: log the image (features, depth) of every N-th frame only (smaller recordings).
    """

    def __init__(self, target: str | Path = "spawn", app_id: str = "vslam", system: Any = None,
                 image_scale: float = 1.0, map_every: int = 10, log_depth: bool = True,
                 jpeg_quality: int | None = 85, image_every: int = 1) -> None:
        rr = _import_rerun()
        if not image_scale >= 1.0:
            raise VslamError(f"image scale {1.0 / image_scale:g}: images can only be shrunk (--viz-scale in (0, 1])")
        if int(image_every) < 1:
            raise VslamError(f"--viz-every {image_every}: log every N-th image, N >= 1")
        self._rr = rr
        self.rec = rr.RecordingStream(app_id)
        self.system = system
        self.image_scale = float(image_scale)
        self.map_every = max(1, int(map_every))
        self.log_depth = log_depth
        self.jpeg_quality = jpeg_quality
        self.image_every = int(image_every)
        self.images_logged = 0
        self.positions: list[np.ndarray] = []
        self._camera_logged = False
        self._last_state: str | None = None
        self._n = 0
        self._failed = False
        target = str(target)
        if target == "spawn":
            try:
                self._spawn(rr)
            except ViewerUnavailable:
                self.rec.disconnect()
                raise
        elif target.startswith("rerun+http") or target.startswith("rerun+https"):
            self.rec.connect_grpc(target)
        else:
            path = Path(target)
            if path.suffix != ".rrd":
                raise VslamError(f"--viz rerun:{target}: a recording file must end in .rrd")
            if not path.parent.exists():
                path.parent.mkdir(parents=True, exist_ok=True)
            self.rec.save(str(path))
        self.target = target
        self.rec.log("world", rr.ViewCoordinates.RDF, static=True)

    def _spawn(self, rr: Any) -> None:
        """Start a viewer for this recording; :class:`ViewerUnavailable` when none can start here."""
        hint = "record with --viz rerun:FILE.rrd and open it with `rerun FILE.rrd` where there is a display"
        reason = no_display_reason()
        if reason is not None:
            raise ViewerUnavailable(f"--viz rerun: no viewer can open here ({reason}); {hint}")
        exe = rerun_executable()
        if exe is None:
            raise ViewerUnavailable("--viz rerun: the rerun viewer executable was not found (next to "
                                    f"{sys.executable} or on PATH); {hint}")
        try:
            rr.spawn(executable_path=exe, recording=self.rec)
        except Exception as exc:  # noqa: BLE001 - rerun raises its own errors (gRPC, process start)
            raise ViewerUnavailable(f"--viz rerun: the viewer did not start ({type(exc).__name__}: {exc}); "
                                    f"{hint}") from None

    @classmethod
    def from_spec(cls, spec: str, **kwargs: Any) -> "RerunViewer":
        """``rerun`` -> spawn a viewer; ``rerun:FILE.rrd`` -> record; ``rerun:rerun+http://...`` -> connect."""
        if spec == "rerun":
            return cls("spawn", **kwargs)
        if spec.startswith("rerun:") and len(spec) > 6:
            return cls(spec[6:], **kwargs)
        raise VslamError(f"--viz {spec!r}: use rerun, rerun:FILE.rrd or rerun:rerun+http://HOST:PORT/proxy")

    # ------------------------------------------------------------------ logging
    def bind(self, system: Any = None) -> Callable[[Any, Any], None]:
        """A two-argument ``on_frame(frame, result)`` callback for :func:`vslam.runner.run_sequence`."""
        if system is not None:
            self.system = system
        return self._guarded_on_frame

    def _guarded_on_frame(self, frame: Any, result: Any) -> None:
        """:meth:`on_frame`; a viewer failure is warned about once and stops the logging, never the run."""
        if self._failed:
            return
        try:
            self.on_frame(frame, result, self.system)
        except Exception as exc:  # noqa: BLE001 - the viewer is optional to the run
            self._failed = True
            log.warning("the rerun viewer failed (%s: %s); the run goes on without it", type(exc).__name__, exc)

    def _log_camera(self, camera: Any, shape: tuple[int, ...]) -> None:
        rr = self._rr
        s = self.image_scale
        K = np.array(camera.K, dtype=float).copy()
        K[:2] *= 1.0 / s if s != 1.0 else 1.0
        h, w = shape[:2]
        self.rec.log("world/camera/image", rr.Pinhole(image_from_camera=K, resolution=[w, h],
                                                      camera_xyz=rr.ViewCoordinates.RDF), static=True)
        self._camera_logged = True

    def _scaled(self, image: np.ndarray) -> np.ndarray:
        if self.image_scale == 1.0:
            return image
        import cv2

        h, w = image.shape[:2]
        size = (max(1, int(round(w / self.image_scale))), max(1, int(round(h / self.image_scale))))
        return cv2.resize(image, size, interpolation=cv2.INTER_AREA if image.dtype == np.uint8 else cv2.INTER_NEAREST)

    def on_frame(self, frame: Any, track_result: Any, system: Any = None) -> None:
        """Log one tracked frame (image, pose, features, trajectory so far, map points)."""
        rr = self._rr
        rec = self.rec
        system = system if system is not None else self.system
        self._n += 1
        rec.set_time("frame", sequence=int(frame.index))
        rec.set_time("time", duration=float(frame.timestamp))
        image = getattr(frame, "image", None)
        if image is not None and (self._n - 1) % self.image_every == 0:
            self.images_logged += 1
            img = self._scaled(image)
            if not self._camera_logged and getattr(frame, "camera", None) is not None:
                self._log_camera(frame.camera, img.shape)
            archetype = rr.Image(img, color_model="BGR" if img.ndim == 3 else "L")
            if self.jpeg_quality is not None:
                archetype = archetype.compress(jpeg_quality=self.jpeg_quality)
            rec.log("world/camera/image", archetype)
            depth = getattr(frame, "depth", None)
            if self.log_depth and depth is not None:
                rec.log("world/camera/image/depth", rr.DepthImage(self._scaled(depth), meter=1.0))
            kp = keypoints_of(track_result, system)
            if kp is not None and len(kp[0]):
                uv, in_map = kp
                colors = None
                if in_map is not None and len(in_map) == len(uv):
                    colors = np.where(in_map[:, None], [[40, 200, 40]], [[230, 120, 20]]).astype(np.uint8)
                rec.log("world/camera/image/keypoints", rr.Points2D(uv / self.image_scale, colors=colors, radii=2.0))
        T = getattr(track_result, "T_world_cam", None)
        state = getattr(track_result, "state", None)
        if T is not None:
            T = np.asarray(T, dtype=float)
            rec.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
            self.positions.append(T[:3, 3].copy())
            if len(self.positions) >= 2:
                rec.log("world/trajectory", rr.LineStrips3D([np.asarray(self.positions)], colors=[[255, 140, 0]]))
        if state is not None and state != self._last_state:
            rec.log("log", rr.TextLog(f"frame {frame.index}: tracking {state}"))
            self._last_state = state
        n_inliers = getattr(track_result, "n_inliers", None)
        if n_inliers is not None:
            rec.log("status/inliers", rr.Scalars(float(n_inliers)))
        if getattr(track_result, "is_keyframe", False) or self._n % self.map_every == 1:
            xyz = map_points_of(system)
            if xyz is not None and len(xyz):
                rec.log("world/map_points", rr.Points3D(xyz, radii=0.01, colors=[[120, 120, 220]]))

    def __call__(self, frame: Any, track_result: Any) -> None:
        self.on_frame(frame, track_result, self.system)

    def close(self) -> None:
        """Flush and end the recording (the .rrd file is complete after this). A viewer that went
        away (gRPC errors) is a warning: the run it showed has finished and written its outputs."""
        try:
            try:
                xyz = map_points_of(self.system)
                if xyz is not None and len(xyz) and not self._failed:
                    self.rec.log("world/map_points", self._rr.Points3D(xyz, radii=0.01, colors=[[120, 120, 220]]))
                self.rec.flush()
            finally:
                self.rec.disconnect()
        except Exception as exc:  # noqa: BLE001 - never turn a finished run into a failure
            log.warning("the rerun viewer could not be closed cleanly (%s: %s); the run's outputs are complete",
                        type(exc).__name__, exc)

    def __enter__(self) -> "RerunViewer":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
