"""Per-frame work that needs no tracking state: grayscale conversion, feature detection and, for a
stereo pair, the depth of the detected keypoints.

:class:`FramePreparer` is what :meth:`vslam.frontend.tracker.Tracker.prepare` runs. It is a small
picklable callable (the detector is created lazily and never pickled), so it can run ahead of the
tracker in another thread or in another process (:func:`vslam.datasets.prefetch.prefetch_process`);
the tracker then adopts the result with :meth:`~vslam.frontend.tracker.Tracker.adopt_prepared`.
Detection and stereo matching are deterministic, so where they run never changes a trajectory.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from vslam.datasets.frame import Frame
from vslam.features.config import FeatureConfig
from vslam.geometry.camera import PinholeCamera


@dataclass
class Detection:
    """Features detected ahead with their stereo ``(depth, u_right)`` (each ``(N,)``, NaN where
    unmatched), as :meth:`vslam.frontend.observe.Observer.add_depth` finds them for a fresh
    detection (no disparity guess)."""

    features: Any
    stereo: tuple[np.ndarray, np.ndarray]


class FramePreparer:
    """``preparer(frame) -> (gray, features or None)``.

    Features are detected only for ``association="match"`` (KLT tracking detects with a mask that
    depends on the tracks, so it cannot be done ahead). Given a ``camera`` and the
    ``frontend.depth`` settings ``depth_cfg`` with ``sensor="stereo"``, the features come as a
    :class:`Detection` with their depth from the right image
    (:func:`vslam.frontend.observation.stereo_pair_depth`).
    """

    def __init__(self, features: FeatureConfig, association: str, camera: PinholeCamera | None = None,
                 sensor: str = "mono", depth_cfg: Any = None) -> None:
        self.features = features
        self.association = association
        self.camera = camera
        self.stereo = sensor == "stereo" and camera is not None and depth_cfg is not None
        self.depth_cfg = depth_cfg
        self._detector = None

    def __call__(self, frame: Frame) -> tuple[np.ndarray, Any]:
        gray = frame.gray
        feats = None
        if self.association == "match":
            if self._detector is None:
                from vslam.features.detect import create_detector

                self._detector = create_detector(self.features)
            feats = self._detector.detect(gray)
            if self.stereo and frame.image_right is not None:  # else the tracker reports the missing image
                from vslam.frontend.observation import stereo_pair_depth

                uv = np.asarray(feats.uv, dtype=float).reshape(-1, 2)
                feats = Detection(feats, stereo_pair_depth(frame, gray, uv, self.camera, self.depth_cfg))
        return gray, feats

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_detector"] = None
        return state
