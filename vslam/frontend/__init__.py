"""Visual odometry: association, per-sensor motion estimation, keyframe choice, monocular init.

``Tracker`` (in :mod:`vslam.frontend.tracker`) is driven by :class:`vslam.system.System`.
"""
from vslam.frontend.config import FrontendConfig

__all__ = ["FrontendConfig"]
