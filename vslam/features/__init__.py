"""vslam.features: detection/description, descriptor matching, KLT tracking, stereo disparity refinement.

Public API::

    det = create_detector(FeatureConfig(detector="orb"))   # once
    feats = det.detect(gray)                                # Features(uv, descriptors, octave, ...)
    i1, i2, dist = match_descriptors(f1.descriptors, f2.descriptors, f1.binary)
    curr_uv, ok = track_klt(prev_gray, curr_gray, prev_uv, KLTConfig())
    new_uv = detect_new_points(gray, existing_uv, max_total=1000, min_distance=15)
    disp, ok = refine_disparity_row(left_gray, right_gray, uv_left, disparity_guess)
"""
from __future__ import annotations

from vslam.features.config import FeatureConfig, KLTConfig, MatcherConfig
from vslam.features.detect import Features, build_pyramid, create_detector, describe_orb, grid_select
from vslam.features.klt import detect_new_points, occupancy_mask, track_klt
from vslam.features.match import (
    descriptor_distances,
    hamming_matrix,
    knn,
    match_descriptors,
)
from vslam.features.stereo import refine_disparity_row, stereo_depth

__all__ = [
    "FeatureConfig", "KLTConfig", "MatcherConfig",
    "Features", "build_pyramid", "create_detector", "describe_orb", "grid_select",
    "detect_new_points", "occupancy_mask", "track_klt",
    "descriptor_distances", "hamming_matrix", "knn", "match_descriptors",
    "refine_disparity_row", "stereo_depth",
]
