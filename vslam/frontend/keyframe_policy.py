"""When to insert a keyframe (after ORB-SLAM's NeedNewKeyFrame, Mur-Artal et al. 2015, sec. V-E)."""
from __future__ import annotations

from vslam.frontend.config import FrontendConfig


def need_keyframe(
    cfg: FrontendConfig,
    frames_since_kf: int,
    n_tracked_ref: int,
    n_ref_points: int,
    n_inliers: int,
    translation_m: float = 0.0,
    force: bool = False,
    tracked_ratio: float | None = None,
) -> bool:
    """True when the current frame should become a keyframe.

    Args:
        frames_since_kf: frames since the last keyframe.
        n_tracked_ref: map points of the reference keyframe matched in this frame.
        n_ref_points: map points the reference keyframe observes.
        n_inliers: pose inliers of this frame.
        translation_m: distance from the reference keyframe (only used with ``keyframes.translation_m > 0``).
        force: a caller-side reason (e.g. KLT re-detection, few close points).
        tracked_ratio: overrides ``cfg.keyframes.tracked_ratio`` (monocular uses a higher one).
    """
    if frames_since_kf < cfg.keyframes.min_frames:
        return False
    if force or frames_since_kf >= cfg.keyframes.max_frames:
        return True
    ratio = cfg.keyframes.tracked_ratio if tracked_ratio is None else tracked_ratio
    if n_ref_points > 0 and n_tracked_ref < ratio * n_ref_points:
        return True
    if cfg.keyframes.translation_m > 0 and translation_m > cfg.keyframes.translation_m:
        return True
    return False
