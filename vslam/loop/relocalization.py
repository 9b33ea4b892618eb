"""Relocalization of a frame whose tracking failed (ORB-SLAM, Mur-Artal et al. 2015, sec. V-C).

The frame's BoW vector ranks the keyframes of the database by raw L1 score (eq. (3) of
Galvez-Lopez & Tardos 2012); for each of the best ``max_candidates`` keyframes, the frame's
descriptors are matched to the map points of that keyframe and its covisible neighbours,
PnP RANSAC (or a 3D-3D alignment when the frame has depth) gives a pose, guided matching by
projection and robust pose refinement give the inliers (:func:`vslam.loop.verification.verify`);
the first candidate with ``min_inliers`` inliers wins.

For RGB-D / stereo the candidate keyframe's keypoints with depth (not only its map points) take
part in the 3D-3D RANSAC, which matters on texture-poor scenes where keyframes keep few points.

:meth:`Relocalizer.recover` is the tracker's first fallback (ORB-SLAM's ``TrackReferenceKeyFrame``):
the same verification against known recent keyframes (no place recognition), with lower thresholds
(``recover_min_matches`` / ``recover_min_inliers``); on TUM fr3/cabinet (58 wide-baseline keyframes)
it recovers 20-45-inlier poses where the constant-velocity prediction misleads guided matching.

Hook for the tracker (the System builds ``system.relocalizer``; the tracker would call it when
``_pose_against_map`` fails, before counting the frame lost)::

    result = relocalizer(obs, segment=self.segment)   # obs: uv_undist, descriptors, octave, depth, u_right
    if result is not None:
        self.ref_kf = result.keyframe_id; self._local_ids = None
        T, n = self._pose_against_map(obs, result.T_world_cam, relocalize=True)   # track the local map
        if T is None: T, n = result.T_world_cam, result.n_inliers  # (obs.point_ids[result.kp_idx] = result.point_ids)
        self.motion_model.reset(T)
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from vslam.geometry.camera import PinholeCamera
from vslam.loop.config import RelocalizationConfig
from vslam.map.database import KeyframeDatabase
from vslam.loop.verification import Features, verify
from vslam.loop.vocabulary import Vocabulary
from vslam.map.map import Map

log = logging.getLogger(__name__)


@dataclass
class Relocalization:
    """A relocalized frame: its pose, the keyframe it was localized against, the inlier matches."""

    T_world_cam: np.ndarray
    keyframe_id: int
    kp_idx: np.ndarray
    point_ids: np.ndarray
    n_inliers: int


class Relocalizer:
    """Callable ``relocalizer(obs) -> Relocalization | None`` (see the module docstring).

    Args:
        map_: the map.
        camera: intrinsics.
        sensor: ``mono``, ``stereo`` or ``rgbd``.
        vocabulary: BoW vocabulary.
        database: keyframe database (shared with loop closing, which fills it); None: a private
            one, filled by :meth:`add_keyframe`.
        config: thresholds.
        scale_factor: feature pyramid scale.
        bf: ``fx * baseline`` (stereo; RGB-D: the virtual baseline), 0 for monocular.
    """

    def __init__(self, map_: Map, camera: PinholeCamera, sensor: str, vocabulary: Vocabulary,
                 database: KeyframeDatabase | None = None, config: RelocalizationConfig | None = None,
                 scale_factor: float = 1.2, bf: float = 0.0, refine_ransac: bool = False) -> None:
        self.map = map_
        self.camera = camera
        self.sensor = sensor
        self.vocabulary = vocabulary
        self.database = database if database is not None else KeyframeDatabase(vocabulary.n_words)
        self.config = config or RelocalizationConfig()
        self.scale_factor = float(scale_factor)
        self.bf = float(bf)
        # refine the 3D-3D RANSAC pose on reprojection before the guided matching (``refine_ransac``
        # of :func:`vslam.loop.verification.verify`, as the loop closer does); off in SLAM tracking
        self.refine_ransac = bool(refine_ransac)
        self.attempts = 0
        self.successes = 0

    def add_keyframe(self, kf: Any) -> None:
        """Keyframe listener for a private database."""
        if kf.descriptors is not None and kf.descriptors.dtype == np.uint8 and kf.id not in self.database:
            self.database.add(kf.id, self.vocabulary.transform(kf.descriptors)[0])

    def _keypoints_with_depth(self, kf_id: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        """World points of the keyframe's keypoints that have depth but no map point (RGB-D / stereo)."""
        kf = self.map.keyframes[kf_id]
        if self.sensor == "mono" or kf.descriptors is None:
            return None, None
        ok = np.isfinite(kf.depth) & (kf.depth > 0) & (kf.point_ids < 0)
        Xc = self.camera.backproject(kf.uv_undist[ok], kf.depth[ok])
        return Xc @ kf.T_world_cam[:3, :3].T + kf.T_world_cam[:3, 3], kf.descriptors[ok]

    def candidates(self, descriptors: np.ndarray, segment: int | None = None) -> list[int]:
        """Keyframe ids by decreasing raw BoW score (at most ``max_candidates``)."""
        bow, _ = self.vocabulary.transform(descriptors)
        ids, scores, _ = self.database.raw_scores(bow, count_common=False)
        if len(ids) == 0:
            return []
        order = np.lexsort((ids, -scores))
        out = []
        for i in ids[order].tolist():
            kf = self.map.keyframes.get(i)
            if kf is None or kf.bad or (segment is not None and kf.segment != segment):
                continue
            out.append(i)
            if len(out) >= self.config.max_candidates:
                break
        return out

    def _features(self, obs: Any, min_matches: int) -> Features | None:
        desc = getattr(obs, "descriptors", None)
        if desc is None or len(desc) < min_matches or desc.dtype != np.uint8:
            return None
        depth = np.asarray(obs.depth, float) if getattr(obs, "depth", None) is not None else np.full(len(desc), np.nan)
        X = None
        if self.sensor != "mono":
            ok = np.isfinite(depth) & (depth > 0)
            X = np.full((len(desc), 3), np.nan)
            X[ok] = self.camera.backproject(obs.uv_undist[ok], depth[ok])
        return Features(obs.uv_undist, desc, obs.octave, depth, getattr(obs, "u_right", None), X)

    def _try(self, feat: Features, kf_ids: list[int], n_covisible: int, min_matches: int, seed: int):
        """Verify ``feat`` against the points of ``kf_ids`` and their ``n_covisible`` strongest
        covisible keyframes; the RANSAC stage also uses the keypoints with depth of ``kf_ids``."""
        cfg = self.config
        group = list(dict.fromkeys(kf_ids + [c for k in kf_ids for c in self.map.covisible(k, n_covisible)]))
        pts = self.map.local_point_ids(group)
        extra = [self._keypoints_with_depth(k) for k in kf_ids]
        extra = [e for e in extra if e[0] is not None and len(e[0])]
        extra_X = np.concatenate([e[0] for e in extra]) if extra else None
        extra_desc = np.concatenate([e[1] for e in extra]) if extra else None
        return verify(feat, self.map.points, pts, self.camera, self.sensor, ratio=cfg.match_ratio,
                      max_distance=cfg.max_descriptor_distance, min_matches=min_matches,
                      search_radius_px=cfg.search_radius_px, scale_factor=self.scale_factor, bf=self.bf,
                      pnp_reproj_px=cfg.reproj_px, seed=seed, extra_X=extra_X, extra_desc=extra_desc,
                      refine_ransac=self.refine_ransac)

    def __call__(self, obs: Any, segment: int | None = None) -> Relocalization | None:
        """Relocalize a frame given its keypoints ``obs`` (attributes ``uv_undist``, ``descriptors``,
        ``octave``, ``depth``, optional ``u_right``); keyframes of ``segment`` only if given."""
        cfg = self.config
        feat = self._features(obs, cfg.min_matches)
        if feat is None:
            return None
        self.attempts += 1
        for kf_id in self.candidates(feat.descriptors, segment):
            ver = self._try(feat, [kf_id], cfg.candidate_covisible, cfg.min_matches, kf_id)
            if ver is not None and max(ver.n_inliers, ver.n_ransac) >= cfg.min_inliers:
                self.successes += 1
                log.info("relocalized against keyframe %d with %d inliers", kf_id, ver.n_inliers)
                return Relocalization(ver.T_world_cam, kf_id, ver.kp_idx, ver.point_ids, ver.n_inliers)
        return None

    def recover(self, obs: Any, kf_ids: list[int]) -> Relocalization | None:
        """Tracking fallback without a motion prediction (wide baselines): the frame against the
        given recent keyframes (the tracker's reference and last keyframes) and their covisible
        neighbours, with no place recognition. As ORB-SLAM's ``TrackReferenceKeyFrame`` (Mur-Artal
        et al. 2015, sec. V-B) the candidates are known, so the thresholds are lower than a global
        relocalization's (``recover_min_matches``, ``recover_min_inliers``): descriptor matches
        (map points, plus the keyframes' keypoints with depth) -> 3D-3D RANSAC with depth (PnP
        without) -> guided matching and pose refinement. The keyframe returned is the first id."""
        cfg = self.config
        kf_ids = [int(k) for k in dict.fromkeys(kf_ids) if k is not None and k in self.map.keyframes]
        feat = self._features(obs, cfg.recover_min_matches)
        if feat is None or not kf_ids:
            return None
        ver = self._try(feat, kf_ids, cfg.recover_covisible, cfg.recover_min_matches, kf_ids[0])
        if ver is None or ver.n_inliers < cfg.recover_min_inliers:
            log.debug("recovery against keyframes %s failed: %s inliers", kf_ids, None if ver is None else ver.n_inliers)
            return None
        log.info("recovered against keyframes %s with %d inliers", kf_ids, ver.n_inliers)
        return Relocalization(ver.T_world_cam, kf_ids[0], ver.kp_idx, ver.point_ids, ver.n_inliers)
