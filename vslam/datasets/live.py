"""Live input: a camera (``camera:0``) or a network stream (``rtsp://``, ``http://`` ...) via OpenCV.

``vslam run camera:0 --camera camera.yaml -o out`` tracks what the camera sees now. Unlike a
recorded sequence a live source cannot wait for the tracker, so a reader thread grabs frames as
fast as the source delivers them and keeps only the newest one (a one-slot mailbox): when the
tracker is still busy with the previous frame when a new one arrives, the waiting frame is
replaced and counted as *dropped* (:attr:`LiveDataset.dropped`, ``dropped_frames`` in
``stats.json``). The tracker therefore always works on the most recent image and never falls
further and further behind. Frame indices are the capture's own count, so a dropped frame leaves
a gap in them.

Sources (:func:`parse_live_source`): ``camera:N`` (device index N), ``camera:/dev/videoN`` (a
device path), or a URL whose scheme is one of :data:`LIVE_SCHEMES`. A calibration is required
(``--camera FILE``; ``vslam calibrate`` writes one); a fisheye calibration remaps every image to a
pinhole camera as for files. Live input is mono.

Timestamps (``clock``): ``wall`` (default) is the UNIX time at which the frame was grabbed;
``index`` is ``capture index / fps`` (replaying a stream, tests).

The stream ends when the source ends (``read`` fails :attr:`LiveDataset.read_retries` times in a
row), when :meth:`LiveDataset.stop` is called (``vslam run`` calls it on Ctrl-C, so the run ends
normally and writes all its outputs), or when the capture raises :class:`KeyboardInterrupt`.
"""
from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from vslam.datasets.frame import Frame
from vslam.errors import CalibrationError, DatasetError
from vslam.geometry.camera import PinholeCamera

log = logging.getLogger(__name__)

#: URL schemes read as a live stream (OpenCV/FFmpeg open them)
LIVE_SCHEMES = ("rtsp", "rtsps", "rtmp", "http", "https", "udp", "tcp", "srt")
CLOCKS = ("wall", "index")
DEFAULT_FPS = 30.0


def is_live_source(spec: Any) -> bool:
    """True for ``camera:...`` and stream URLs (``rtsp://`` ...), which are not paths."""
    if not isinstance(spec, str):
        return False
    low = spec.lower()
    return low.startswith("camera:") or any(low.startswith(s + "://") for s in LIVE_SCHEMES)


def parse_live_source(spec: str) -> int | str:
    """What to hand ``cv2.VideoCapture``: the device index of ``camera:N``, the device path of
    ``camera:/dev/videoN``, or the URL itself."""
    if spec.lower().startswith("camera:"):
        rest = spec[len("camera:"):].strip()
        if rest.isdigit():
            return int(rest)
        if rest.startswith("/dev/"):
            return rest
        raise DatasetError(f"{spec!r}: use camera:N (a device index, e.g. camera:0) or camera:/dev/videoN")
    if not is_live_source(spec):
        raise DatasetError(f"{spec!r} is not a live source; use camera:N or a {'/'.join(LIVE_SCHEMES)} URL")
    return spec


class _Mailbox:
    """One slot holding the newest frame; a frame replaced before it was taken counts as dropped."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.item: tuple[int, float, np.ndarray] | None = None
        self.ended = False
        self.error: BaseException | None = None
        self.captured = self.delivered = self.dropped = 0

    def put(self, item: tuple[int, float, np.ndarray]) -> None:
        with self.cond:
            if self.item is not None:
                self.dropped += 1
            self.item = item
            self.captured += 1
            self.cond.notify()

    def end(self, error: BaseException | None = None) -> None:
        with self.cond:
            self.ended = True
            self.error = error
            self.cond.notify_all()

    def take(self, stopped: threading.Event) -> tuple[int, float, np.ndarray] | None:
        """The newest frame (waiting for one), or None once the source ended or ``stopped`` is set."""
        with self.cond:
            while self.item is None and not self.ended and not stopped.is_set():
                self.cond.wait(0.1)  # wakes up for stop() from a signal handler too
            if stopped.is_set():
                return None
            if self.item is None:
                if self.error is not None:
                    raise self.error
                return None
            item, self.item = self.item, None
            self.delivered += 1
            return item


class LiveDataset:
    """Frames of a live camera or stream, newest first (see the module docstring).

    Duck-compatible with :class:`~vslam.datasets.base.Dataset` for what a run needs (``camera``,
    ``sensor``, ``sensors``, ``frame_rate``, ``frames()``, ``ground_truth()``, ``skipped``) but
    without a length: the stream lasts until it ends or is stopped.

    Args:
        source: ``camera:N``, ``camera:/dev/videoN`` or a stream URL.
        camera: the calibration (a file in any format :func:`vslam.datasets.calibration.read_camera_file`
            reads, or a :class:`PinholeCamera`); required.
        fps: the frame rate (for ``clock="index"`` and the stats); default the calibration's
            ``fps``, else what the capture reports, else 30.
        clock: ``wall`` or ``index`` timestamps.
        read_retries: consecutive failed reads that end the stream.
    """

    kind = "live"
    sensors = ("mono",)
    sensor = "mono"
    skipped = 0

    def __init__(self, source: str, sensor: str | None = None, camera: PinholeCamera | str | Path | None = None,
                 fps: float | None = None, clock: str = "wall", read_retries: int = 3) -> None:
        import cv2

        from vslam.datasets.folder import _resolve_camera

        if sensor not in (None, "mono"):
            raise DatasetError(f"{source}: live input is mono only, not {sensor!r}")
        if clock not in CLOCKS:
            raise DatasetError(f"clock {clock!r} unknown; use one of {', '.join(CLOCKS)}")
        if camera is None:
            raise CalibrationError(
                f"{source}: live input needs a calibration: pass --camera FILE (camera.yaml, OpenCV, ORB-SLAM, "
                f"Kalibr, ROS camera_info; `vslam calibrate` writes one)")
        self.source = source
        self.name = source
        self.root = source
        self.clock = clock
        self.read_retries = max(1, int(read_retries))
        self._target = parse_live_source(source)
        self._cap = cv2.VideoCapture(self._target)
        if not self._cap.isOpened():
            self._cap.release()
            raise DatasetError(f"{source}: OpenCV cannot open this {'camera' if isinstance(self._target, int) else 'stream'}; "
                               f"check that it is connected (and not in use) or that the URL plays (e.g. in ffplay)")
        self._cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # drivers that honour it hand out fresh frames only
        ok, first = self._read()
        if not ok or first is None:
            self._cap.release()
            raise DatasetError(f"{source}: opened, but no frame arrived; check the camera or stream")
        self._first = (0, self._now(0), first)
        size = (first.shape[1], first.shape[0])
        self.camera, extras, self._rectifier, self.calibration_source = _resolve_camera(camera, [], size, Path(str(source)))
        raw = self._rectifier.calibration.camera if self._rectifier is not None else self.camera
        if (raw.width, raw.height) != size:
            self._cap.release()
            raise CalibrationError(f"{source}: frames are {size[0]}x{size[1]} but the calibration "
                                   f"({self.calibration_source}) is {raw.width}x{raw.height}; calibrate at the "
                                   f"stream's resolution")
        self._size = size
        cap_fps = float(self._cap.get(cv2.CAP_PROP_FPS) or 0.0)
        self.frame_rate = float(fps or extras.get("fps") or (cap_fps if 0 < cap_fps < 1000 else DEFAULT_FPS))
        self._box = _Mailbox()
        self._stopped = threading.Event()
        self._thread: threading.Thread | None = None

    # -- counts ---------------------------------------------------------------------------------
    @property
    def captured(self) -> int:
        """Frames grabbed from the source so far."""
        return self._box.captured

    @property
    def delivered(self) -> int:
        """Frames handed to the consumer so far."""
        return self._box.delivered

    @property
    def dropped(self) -> int:
        """Frames replaced by a newer one before the consumer took them."""
        return self._box.dropped

    def counts(self) -> dict:
        """``captured_frames``, ``dropped_frames`` (for ``stats.json``)."""
        return {"captured_frames": self.captured, "dropped_frames": self.dropped}

    # -- reading --------------------------------------------------------------------------------
    def _now(self, index: int) -> float:
        if self.clock == "index":
            return index / getattr(self, "frame_rate", DEFAULT_FPS)
        return time.time()

    def _read(self) -> tuple[bool, np.ndarray | None]:
        return self._cap.read()

    def _reader(self) -> None:
        box = self._box
        box.put(self._first)
        index = 1
        failures = 0
        try:
            while not self._stopped.is_set():
                ok, image = self._read()
                if not ok or image is None:
                    failures += 1
                    if failures >= self.read_retries:
                        log.info("%s: the stream ended after %d frames", self.source, index)
                        break
                    time.sleep(0.02)
                    continue
                failures = 0
                box.put((index, self._now(index), image))
                index += 1
        except KeyboardInterrupt:
            log.info("%s: capture interrupted after %d frames", self.source, index)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the consumer
            box.end(DatasetError(f"{self.source}: reading a frame failed: {type(exc).__name__}: {exc}"))
            return
        finally:
            self._cap.release()
        box.end()

    def stop(self) -> None:
        """End the stream: the consumer gets no further frame (safe from a signal handler)."""
        self._stopped.set()

    def frames(self, max_frames: int | None = None, counts: dict | None = None) -> Iterator[Frame]:
        """Yield the newest frame whenever the consumer asks, until the stream ends, :meth:`stop`
        is called or ``max_frames`` were yielded. ``counts``, when given, receives
        :meth:`counts` when the iteration ends (for the run's stats)."""
        if self._thread is not None:
            raise DatasetError(f"{self.source}: a live source can be iterated only once")
        self._thread = threading.Thread(target=self._reader, name="vslam-live-reader", daemon=True)
        self._thread.start()
        n = 0
        try:
            while max_frames is None or n < max_frames:
                item = self._box.take(self._stopped)
                if item is None:
                    break
                index, timestamp, image = item
                yield self._frame(index, timestamp, image)
                n += 1
        finally:
            self.stop()
            self._thread.join(timeout=5.0)
            if counts is not None:
                counts.update(self.counts())

    def __iter__(self) -> Iterator[Frame]:
        return self.frames()

    def _frame(self, index: int, timestamp: float, image: np.ndarray) -> Frame:
        h, w = image.shape[:2]
        if (w, h) != self._size:
            raise DatasetError(f"{self.source}: frame {index} is {w}x{h}, the stream started at "
                               f"{self._size[0]}x{self._size[1]}; the source changed resolution")
        if self._rectifier is not None:
            image = self._rectifier.left(image)
        return Frame(index=index, timestamp=float(timestamp), image=image, camera=self.camera,
                     path=f"{self.source}#{index}")

    def ground_truth(self) -> None:
        """A live source has no ground truth."""
        return None

    def close(self) -> None:
        """Release the capture (when never iterated)."""
        self.stop()
        if self._thread is None:
            self._cap.release()

    def __repr__(self) -> str:
        return f"LiveDataset(source={self.source!r}, frame_rate={self.frame_rate:g}, dropped={self.dropped})"
