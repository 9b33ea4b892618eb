"""Per-frame work that needs no tracking state: grayscale conversion and feature detection.

:class:`FramePreparer` is what :meth:`vslam.frontend.tracker.Tracker.prepare` runs. It is a small
picklable callable (the detector is created lazily and never pickled), so it can run ahead of the
tracker in another thread or in another process (:func:`vslam.datasets.prefetch.prefetch_process`);
the tracker then adopts the result with :meth:`~vslam.frontend.tracker.Tracker.adopt_prepared`.
Detection is deterministic, so where it runs never changes a trajectory.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from vslam.datasets.frame import Frame
from vslam.features.config import FeatureConfig


class FramePreparer:
    """``preparer(frame) -> (gray, features or None)``.

    Features are detected only for ``association="match"`` (KLT tracking detects with a mask that
    depends on the tracks, so it cannot be done ahead).
    """

    def __init__(self, features: FeatureConfig, association: str) -> None:
        self.features = features
        self.association = association
        self._detector = None

    def __call__(self, frame: Frame) -> tuple[np.ndarray, Any]:
        gray = frame.gray
        feats = None
        if self.association == "match":
            if self._detector is None:
                from vslam.features.detect import create_detector

                self._detector = create_detector(self.features)
            feats = self._detector.detect(gray)
        return gray, feats

    def __getstate__(self) -> dict:
        return {"features": self.features, "association": self.association, "_detector": None}
