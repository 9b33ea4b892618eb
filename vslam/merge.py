"""Merge two saved maps offline (the API behind ``vslam merge``; issue #18, multi-session maps).

``merge_paths(MAP_A, MAP_B, OUT)`` joins the map of ``MAP_B`` into the map of ``MAP_A`` (both the
``--output`` folders of ``vslam run``, or any folder holding a ``map/``), after ORB-SLAM3's Atlas
merging (Campos et al., T-RO 2021, sec. VI-B):

1. **Place recognition.** Every keyframe of B queries A's keyframe database (bag of words); each of
   its best ``candidates`` is verified geometrically (:func:`vslam.loop.verification.verify`:
   descriptor matching to the candidate's and its covisible keyframes' map points, 3D-3D RANSAC,
   SE(3) from depth, Sim(3) from B's own map points for monocular maps, then guided matching and
   pose refinement), accepted with ``loop.closing.min_inliers`` (``min_inliers_mono``) map-point inliers.
2. **Alignment.** Each accepted match gives ``S_A_B = S_world_cam(match) T_world_cam(B kf)^-1`` (two
   gravity-aligned visual-inertial maps: its yaw + translation only, as everything below); the
   largest group of matches agreeing within ``agree_m`` (relative ``agree_rel`` of A's extent for
   monocular) and ``agree_deg`` wins and must hold ``min_agreeing`` B keyframes, else the maps do not
   overlap (:class:`vslam.errors.MergeError`). The transform is re-estimated over all their 3D-3D
   correspondences (:func:`vslam.geometry.align.align_points`, Umeyama; LMedS).
3. **Append** B into A under ``S_A_B`` (:func:`vslam.map.append.append_map`, ids shifted; B's matched
   segment joins A's; the segment table records the source and transform).
4. **Weld.** The matched duplicates are fused (A's point survives) and A's points of the matched
   places are projected into the seam keyframes of B and their covisible keyframes and fused too
   (SearchAndFuse); covisibility is rebuilt; a local BA around the seam
   (:meth:`vslam.backend.local_mapping.LocalMapper.process`, B's best-matched keyframe and its
   covisible window), then a global BA (A's first keyframe fixed; two for monocular) spread the seam.

Outputs in ``OUT``: ``map/`` (format version 2, with the merged keyframe database), ``keyframes.txt``
(TUM, ``T_world_cam`` in A's world, good keyframes by timestamp; one per timestamp, A's first when
overlapping inputs both made a keyframe of one frame), ``sparse.ply``, ``topology.*``,
``config.yaml`` (A's, so ``vslam localize OUT`` detects features as the runs did) and ``stats.json``.

Example::

    from vslam.merge import merge_paths
    result = merge_paths("runs/kitchen_a", "runs/kitchen_b", "runs/kitchen_ab")
    print(result.stats["seam_keyframes"], result.stats["S_a_b"])
"""
from __future__ import annotations

import logging
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from vslam.errors import ConfigError, MapFormatError, MergeError
from vslam.map.pose_graph_4dof import align_points_4dof, yaw_correction

log = logging.getLogger(__name__)


@dataclass
class MergeOptions:
    """Place recognition and alignment settings of :func:`merge_maps` (verification uses ``loop.closing``).

    Attributes:
        candidates: A's keyframes (best BoW scores) verified per keyframe of B.
        min_agreeing: B keyframes whose verified transforms must agree to accept the overlap.
        agree_m, agree_deg: two transforms agree when they place the matched B keyframes within
            ``agree_m`` metres and ``agree_deg`` degrees of each other (metric maps).
        agree_rel: monocular: ``agree_m`` relative to the extent of A's keyframe centres (scale unknown).
        weak_inliers: a match with fewer map-point inliers than ``loop.closing.min_inliers`` (but at
            least this many) does not vote on the alignment, but joins the seam (its points are fused)
            when it agrees with the alignment: a second place where B revisits A, e.g. B's end closing
            a loop onto A's start, is welded too.
        local_ba, global_ba: run the seam's local BA / the global BA.
        threads: threads verifying B's keyframes (:func:`find_seam`; the result does not depend on it).
    """

    candidates: int = 3
    min_agreeing: int = 2
    agree_m: float = 0.10
    agree_deg: float = 5.0
    agree_rel: float = 0.05
    weak_inliers: int = 15
    local_ba: bool = True
    global_ba: bool = True
    threads: int = 1

    def __post_init__(self) -> None:
        if self.candidates < 1 or self.min_agreeing < 1 or self.weak_inliers < 6 or self.threads < 1:
            raise ConfigError("merge: candidates, min_agreeing and threads must be >= 1, weak_inliers >= 6")
        if not (self.agree_m > 0 and self.agree_deg > 0 and self.agree_rel > 0):
            raise ConfigError("merge: agree_m, agree_deg and agree_rel must be positive")


@dataclass
class SeamMatch:
    """One verified place-recognition match: keyframe ``b_kf`` of B seen in A at ``a_kf``."""

    b_kf: int
    a_kf: int
    score: float
    ver: Any  # vslam.loop.verification.Verified
    S_a_b: np.ndarray
    X_b: np.ndarray  # (n_inliers, 3) B-world points of the inlier keypoints (NaN where unknown)


@dataclass
class MergeResult:
    stats: dict
    S_a_b: np.ndarray
    map: Any = None
    database: Any = None
    output_dir: Path | None = None
    matches: list[SeamMatch] = field(default_factory=list)


# ============================================================================ place recognition
def find_seam(map_a, db_a, map_b, db_b, camera, sensor: str, cfg, vocabulary,
              options: MergeOptions) -> list[SeamMatch]:
    """Every keyframe of B verified against its best BoW candidates in A (step 1 of the module
    docstring). The database queries run first, in this thread; the verifications (read-only on
    both maps, each seeded by its B keyframe's id) in ``options.threads`` threads, their results
    taken in B's keyframe order: the same matches whatever the threads."""
    from vslam.geometry.camera import stereo_bf
    from vslam.geometry.lie import inv_se3
    from vslam.loop.verification import keyframe_features, keypoints_with_depth, verify

    cc = cfg.loop.closing
    need = min(options.weak_inliers, cc.min_inliers_mono if sensor == "mono" else cc.min_inliers)
    bf = stereo_bf(camera, sensor)
    scale_factor = cfg.features.scale_factor
    jobs = []  # (B keyframe, its features, A candidate id, BoW score, A's group)
    for kf in sorted(map_b.keyframes.values(), key=lambda k: k.id):
        if kf.bad or kf.descriptors is None or kf.descriptors.dtype != np.uint8 or len(kf.descriptors) < 2:
            continue
        bow = db_b.bow(kf.id) if db_b is not None and kf.id in db_b else vocabulary.transform(kf.descriptors)[0]
        feat = keyframe_features(map_b, kf, camera, sensor)
        for a_id, score in db_a.query(bow, max_results=options.candidates):
            a_kf = map_a.keyframes.get(a_id)
            if a_kf is None or a_kf.bad:
                continue
            group = [a_id] + [k for k in map_a.covisible(a_id, cc.candidate_neighbours) if not map_a.keyframes[k].bad]
            jobs.append((kf, feat, a_id, score, group))

    def run(job):
        kf, feat, _, _, group = job
        pts = map_a.local_point_ids(group)
        extra = {} if sensor == "mono" or not cc.match_keypoints_with_depth else \
            keypoints_with_depth(map_a, group[: 1 + cc.depth_keypoint_neighbours], camera)
        return verify(feat, map_a.points, pts, camera, sensor, ratio=cc.match_ratio,
                      max_distance=cc.max_descriptor_distance, min_matches=cc.min_matches,
                      align_threshold_m=cc.align_threshold_m, align_threshold_rel=cc.align_threshold_rel,
                      search_radius_px=cc.search_radius_px, scale_factor=scale_factor, bf=bf, seed=kf.id,
                      refine_ransac=cc.refine_ransac_pose, guided_max_distance=cc.guided_max_descriptor_distance,
                      guided_ratio=cc.guided_ratio, min_search_radius_px=cc.min_search_radius_px, **extra)

    if options.threads > 1 and len(jobs) > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(options.threads) as pool:
            verified = list(pool.map(run, jobs))
    else:
        verified = [run(job) for job in jobs]
    best: dict[int, tuple] = {}  # B keyframe id -> (A id, verification, score, keyframe, features)
    for (kf, feat, a_id, score, _), ver in zip(jobs, verified):
        if ver is None or ver.n_inliers < need:
            continue
        if kf.id not in best or ver.n_inliers > best[kf.id][1].n_inliers:
            best[kf.id] = (a_id, ver, score, kf, feat)
    matches: list[SeamMatch] = []
    for a_id, ver, score, kf, feat in best.values():
        S = ver.S_world_cam @ inv_se3(kf.T_world_cam)
        Xc = feat.X_cam[ver.kp_idx]
        X_b = Xc @ kf.T_world_cam[:3, :3].T + kf.T_world_cam[:3, 3]
        matches.append(SeamMatch(kf.id, a_id, float(score), ver, S, X_b))
        log.debug("B keyframe %d (frame %d) -> A keyframe %d: %d inliers", kf.id, kf.frame_index, a_id, ver.n_inliers)
    return matches


def _rot_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def agreeing_group(matches: list[SeamMatch], map_b, tolerance: float, agree_deg: float) -> list[SeamMatch]:
    """The largest set of matches whose transforms agree with one of them (ties: more inliers):
    ``S_i`` and ``S_j`` agree when they place both matched B keyframe centres within ``tolerance``
    and differ by less than ``agree_deg`` in rotation."""
    if not matches:
        return []
    centres = np.stack([map_b.keyframes[m.b_kf].T_world_cam[:3, 3] for m in matches])
    best: list[SeamMatch] = []
    for i, mi in enumerate(matches):
        group = []
        for j, mj in enumerate(matches):
            c = centres[[i, j]]
            d = np.linalg.norm((c @ mi.S_a_b[:3, :3].T + mi.S_a_b[:3, 3]) - (c @ mj.S_a_b[:3, :3].T + mj.S_a_b[:3, 3]),
                               axis=1).max()
            Ri = mi.S_a_b[:3, :3] / np.cbrt(np.linalg.det(mi.S_a_b[:3, :3]))
            Rj = mj.S_a_b[:3, :3] / np.cbrt(np.linalg.det(mj.S_a_b[:3, :3]))
            if d <= tolerance and _rot_deg(Ri.T @ Rj) <= agree_deg:
                group.append(mj)
        key = (len(group), sum(m.ver.n_inliers for m in group))
        if key > (len(best), sum(m.ver.n_inliers for m in best)):
            best = group
    return best


def _agrees(m: SeamMatch, S: np.ndarray, map_b, tolerance: float, agree_deg: float) -> bool:
    """Whether match ``m`` places its B keyframe within ``tolerance`` / ``agree_deg`` of where ``S`` does."""
    T = map_b.keyframes[m.b_kf].T_world_cam
    A = S @ T
    B = m.S_a_b @ T
    R = (A[:3, :3] / np.cbrt(np.linalg.det(A[:3, :3]))).T @ (B[:3, :3] / np.cbrt(np.linalg.det(B[:3, :3])))
    return bool(np.linalg.norm(A[:3, 3] - B[:3, 3]) <= tolerance and _rot_deg(R) <= agree_deg)


def _rms_residual(S: np.ndarray, src: np.ndarray, dst: np.ndarray) -> float:
    """RMS distance between ``S`` applied to ``src`` and ``dst`` (``(N, 3)``; finite rows only)."""
    ok = np.all(np.isfinite(src), axis=1) & np.all(np.isfinite(dst), axis=1)
    if not ok.any():
        return float("nan")
    d = src[ok] @ S[:3, :3].T + S[:3, 3] - dst[ok]
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def estimate_transform(group: list[SeamMatch], map_a, sensor: str, four_dof: bool = False) -> tuple[np.ndarray, dict]:
    """``(S_A_B, alignment)``: ``S_A_B`` from all 3D-3D correspondences of the agreeing matches
    (B-world point of each inlier keypoint -> A's map point), Umeyama inside LMedS (``four_dof``: two
    gravity-aligned maps, yaw + translation only, :func:`vslam.map.pose_graph_4dof.align_points_4dof`);
    the best single match's when that fails. ``alignment``: its ``inliers`` (correspondences it explains, of
    ``correspondences``) and their RMS ``residual`` (A's map units: metres unless monocular)."""
    from vslam.errors import GeometryError
    from vslam.geometry.align import align_points

    src = np.concatenate([m.X_b for m in group])
    dst = np.concatenate([map_a.points.position[m.ver.point_ids] for m in group])
    ok = np.all(np.isfinite(src), axis=1)
    best = max(group, key=lambda m: m.ver.n_inliers)
    fallback = (best.S_a_b, {"inliers": int(best.ver.n_inliers), "correspondences": int(ok.sum()),
                             "residual": _rms_residual(best.S_a_b, best.X_b, map_a.points.position[best.ver.point_ids]),
                             "from": "best match"})
    if ok.sum() < 6:
        return fallback
    try:
        if four_dof:
            S, inl = align_points_4dof(src[ok], dst[ok])
        else:
            S, inl = align_points(src[ok], dst[ok], with_scale=sensor == "mono", threshold=None)
    except GeometryError as exc:
        log.warning("merge: refining the transform failed (%s); using the best match's", exc)
        return fallback
    log.info("merge: transform from %d correspondences (%d inliers) of %d matches", int(ok.sum()), int(inl.sum()),
             len(group))
    inl = np.asarray(inl, dtype=bool)
    return S, {"inliers": int(inl.sum()), "correspondences": int(ok.sum()),
               "residual": _rms_residual(S, src[ok][inl], dst[ok][inl]), "from": "all seam correspondences"}


# ============================================================================ weld
def _fuse_seam(slam_map, group: list[SeamMatch], kf_offset: int, camera, sensor: str, cfg) -> int:
    """Fuse the seam's duplicates (:func:`vslam.map.segment_merge.fuse_seam`): each match's inliers,
    then A's points of the matched places projected into the seam keyframes of B and their covisible
    keyframes (A's point survives)."""
    from vslam.map.segment_merge import fuse_seam

    cc = cfg.loop.closing
    b_ids = {m.b_kf + kf_offset for m in group}
    a_group = sorted({k for m in group for k in [m.a_kf] + slam_map.covisible(m.a_kf, cc.candidate_neighbours)
                      if k < kf_offset})
    targets = sorted(b_ids | {k for b in b_ids for k in slam_map.covisible(b, cc.candidate_neighbours) if k >= kf_offset})
    matches = [(m.b_kf + kf_offset, m.ver.kp_idx, m.ver.point_ids) for m in group]
    return fuse_seam(slam_map, matches, targets, a_group, camera, sensor, cc.fuse.radius_px,
                     cc.fuse.max_descriptor_distance, cc.fuse.ratio)


def merge_maps(map_a, db_a, map_b, db_b, camera, sensor: str, cfg, *, options: MergeOptions | None = None,
               source_b: str = "", vocabulary=None, b_keyframes: list[int] | None = None) -> MergeResult:
    """Merge ``map_b`` into ``map_a`` (modified in place; returned as ``result.map``) and its database
    into ``db_a`` (steps 1-4 of the module docstring). Raises :class:`MergeError` when no overlap is found.
    ``b_keyframes``: place recognition on these keyframes of B only (where the seam is known: ``vslam map``).

    An inertial ``sensor`` verifies as its base sensor; two gravity-aligned maps (``Map.gravity_aligned``)
    align by a yaw + translation (each match's transform and the fit: both IMUs observe roll and pitch)."""
    from vslam.inertial.sensors import split_sensor
    from vslam.loop.vocabulary import load_default_vocabulary

    sensor = split_sensor(sensor)[0]
    four_dof = bool(map_a.gravity_aligned and map_b.gravity_aligned)
    options = options or MergeOptions()
    t0 = time.perf_counter()
    vocabulary = vocabulary or load_default_vocabulary()
    db_a = _database(map_a, db_a, vocabulary, cfg)
    seam_b = map_b if b_keyframes is None else SimpleNamespace(points=map_b.points, keyframes={
        k: map_b.keyframes[k] for k in sorted(b_keyframes) if k in map_b.keyframes})
    matches = find_seam(map_a, db_a, seam_b, db_b, camera, sensor, cfg, vocabulary, options)
    if four_dof:
        for m in matches:  # each match's world change: its verified pose's yaw + translation only
            m.S_a_b = yaw_correction(map_b.keyframes[m.b_kf].T_world_cam, m.ver.T_world_cam)
    t_pr = time.perf_counter() - t0
    centres = np.stack([k.T_world_cam[:3, 3] for k in map_a.keyframes.values()])
    extent = float(np.linalg.norm(centres - centres.mean(axis=0), axis=1).max()) if len(centres) else 0.0
    tol = options.agree_rel * max(extent, 1e-6) if sensor == "mono" and not four_dof else options.agree_m
    need = cfg.loop.closing.min_inliers_mono if sensor == "mono" else cfg.loop.closing.min_inliers
    strong = [m for m in matches if m.ver.n_inliers >= need]
    group = agreeing_group(strong, map_b, tol, options.agree_deg)
    if len(group) < options.min_agreeing:
        raise MergeError(f"the maps do not overlap: {len(matches)} of {len(seam_b.keyframes)} keyframes of B were "
                         f"verified in A and at most {len(group)} agree on one alignment ({options.min_agreeing} "
                         "needed); map B must revisit a place mapped in A")
    S, alignment = estimate_transform(group, map_a, sensor, four_dof)
    ids = {m.b_kf for m in group}
    weak = [m for m in matches if m.b_kf not in ids and _agrees(m, S, map_b, tol, options.agree_deg)]
    scale = float(np.cbrt(np.linalg.det(S[:3, :3])))
    best = max(group, key=lambda m: m.ver.n_inliers)
    seg_a, seg_b = map_a.keyframes[best.a_kf].segment, map_b.keyframes[best.b_kf].segment
    appended = _append(map_a, map_b, db_a, db_b, S, vocabulary, source_b, {seg_b: seg_a})
    off = appended.kf_offset
    fused = _fuse_seam(map_a, group + weak, off, camera, sensor, cfg)
    for k in sorted(map_a.keyframes):
        if k >= off and map_a.keyframes[k].segment == seg_a:
            map_a.update_covisibility(k)
    cross = sum(1 for k in map_a.keyframes if k >= off for j in map_a.covisibility.get(k, {}) if j < off)
    stats: dict[str, Any] = {
        "keyframes_a": len(map_a.keyframes) - len(map_b.keyframes), "keyframes_b": len(map_b.keyframes),
        "queried_b_keyframes": len(seam_b.keyframes), "verified_b_keyframes": len(strong), "seam_keyframes": len(group),
        "weak_seam_keyframes": len(weak), "seam": [[m.b_kf + off, m.a_kf, int(m.ver.n_inliers)] for m in group + weak],
        "S_a_b": [[round(float(x), 6) for x in row] for row in S], "scale": round(scale, 6),
        "fused_points": int(fused), "cross_links": int(cross), "place_recognition_s": round(t_pr, 2),
        "keyframes": len(map_a.keyframes), "keyframe_id_offset": off, "point_id_offset": appended.point_offset,
        "alignment_inliers": alignment["inliers"], "alignment_correspondences": alignment["correspondences"],
        "alignment_residual": round(alignment["residual"], 6),  # RMS over the inliers, A's units (m unless mono)
        "alignment_dof": 4 if four_dof else 7 if sensor == "mono" else 6,
    }
    log.info("merge: %d/%d B keyframes verified, %d agree; scale %.4f; %d points fused, %d covisibility links "
             "across the seam", len(matches), len(map_b.keyframes), len(group), scale, fused, cross)
    stats.update(_weld(map_a, camera, sensor, cfg, options, best.b_kf + off))
    stats["merge_s"] = round(time.perf_counter() - t0, 2)
    return MergeResult(stats=stats, S_a_b=S, map=map_a, database=db_a, matches=group)


def _database(map_a, db_a, vocabulary, cfg):
    """A's keyframe database: the saved one, else one built from A's descriptors."""
    from vslam.map.database import KeyframeDatabase

    if db_a is not None:
        return db_a
    db_a = KeyframeDatabase(vocabulary.n_words, cfg.loop.database)
    for k in sorted(map_a.keyframes):
        kf = map_a.keyframes[k]
        if kf.descriptors is not None and kf.descriptors.dtype == np.uint8:
            db_a.add(k, vocabulary.transform(kf.descriptors)[0])
    return db_a


def _append(map_a, map_b, db_a, db_b, S: np.ndarray, vocabulary, source_b: str, segment_map: dict):
    """Step 3: B appended into A under ``S`` (:func:`vslam.map.append.append_map`; A's gravity alignment
    is the merged map's), the appended keyframes' IMU velocities turned with ``S``, B's BoW vectors in ``db_a``."""
    from vslam.map.append import append_map

    appended = append_map(map_a, map_b, S, source=source_b, segment_map=segment_map)
    off = appended.kf_offset
    for k in sorted(map_b.keyframes):
        extra = map_a.keyframes[k + off].extra
        if "imu_velocity" in extra:
            extra["imu_velocity"] = S[:3, :3] @ extra["imu_velocity"]
        kf = map_b.keyframes[k]
        if db_b is not None and k in db_b:
            db_a.add(k + off, db_b.bow(k))
        elif kf.descriptors is not None and kf.descriptors.dtype == np.uint8:
            db_a.add(k + off, vocabulary.transform(kf.descriptors)[0])
    return appended


def _weld(map_a, camera, sensor: str, cfg, options: MergeOptions, seam_kf: int) -> dict:
    """Step 4's BAs: the local BA around ``seam_kf`` and the global BA (as ``options`` say); their stats."""
    from vslam.backend.local_mapping import LocalMapper

    stats: dict[str, Any] = {}
    mapper = LocalMapper(map_a, camera, sensor, cfg.backend, cfg.features.scale_factor)
    if options.local_ba:
        t1 = time.perf_counter()
        res = mapper.process(seam_kf)
        stats["local_ba"] = None if res is None else {
            "keyframes": int(res.kf_ids.size) if hasattr(res, "kf_ids") else None,
            "initial_rms_px": round(float(res.initial_rms_px), 4), "final_rms_px": round(float(res.final_rms_px), 4),
            "ms": round(1e3 * (time.perf_counter() - t1), 1)}
    if options.global_ba:
        mapper.global_ba()
        stats["global_ba"] = mapper.global_ba_result
    return stats


# ============================================================================ paths
def _merge_figure(path: Path, result: MergeResult, sensor: str) -> None:
    """``merge.png`` (:func:`vslam.reconstruction.merge_figure.plot_merge`); a failure is a warning."""
    from vslam.reconstruction.merge_figure import plot_merge

    s = result.stats
    try:
        plot_merge(path, result.map, s["keyframe_id_offset"], s["seam"],
                   {"inliers": s["alignment_inliers"], "residual": s["alignment_residual"]},
                   unit="map A units" if sensor == "mono" else "m")
        s["figure"] = str(path)
    except Exception as exc:  # noqa: BLE001 - a plot never fails a finished merge
        log.warning("%s not written (%s: %s)", path, type(exc).__name__, exc)


def _load(path: Path, what: str):
    from vslam.map.io import load_run_map

    return load_run_map(path, f"map {what}", "merge")


def merge_paths(map_a: str | Path, map_b: str | Path, output: str | Path, config: str | Path | Any | None = None,
                overrides: list[str] | tuple[str, ...] = (), options: MergeOptions | None = None) -> MergeResult:
    """Merge the maps saved in ``map_a`` and ``map_b`` into ``output`` (see the module docstring).

    ``config`` defaults to ``MAP_A/config.yaml`` (the mapping run's settings) when there is one.
    Raises :class:`MapFormatError` (missing/corrupt map, different sensors or cameras),
    :class:`MergeError` (no overlap), :class:`OutputError` (output folder unusable).
    """
    from vslam.api import resolve_config
    from vslam.outputs import atomic_path, open_run_dir, refuse_inputs, same_path
    from vslam.reconstruction.map_outputs import write_map_outputs
    from vslam.runner import error_stats_when_stopped, write_error_stats, write_stats
    from vslam.trajectory import Trajectory, write_tum

    a, b, out = Path(map_a), Path(map_b), Path(output)
    refuse_inputs(out, (a, b, a / "map", b / "map"), "merged map")  # before the maps are read
    if same_path(a, b) or same_path(a / "map", b / "map"):
        raise MergeError(f"{b}: is the same map as {a}; merge two different maps")
    if config is None and (a / "config.yaml").is_file():
        config = a / "config.yaml"
    inputs, paths = (a, b, a / "map", b / "map"), {"map_a": str(a.resolve()), "map_b": str(b.resolve())}
    with error_stats_when_stopped(out, inputs, paths):  # a SIGTERM while the maps load: stats.json says so
        cfg = resolve_config(config, list(overrides))
        map_A, db_A, cam_A, meta_A = _load(a, "A")
        map_B, db_B, cam_B, meta_B = _load(b, "B")
    from vslam.inertial.sensors import ALL_SENSORS as SENSORS  # inertial: a yaw + translation when both are aligned

    sensor = meta_A.get("sensor")
    if sensor != meta_B.get("sensor") or sensor not in SENSORS:
        raise MapFormatError(f"cannot merge a {meta_A.get('sensor')!r} map ({a}) with a {meta_B.get('sensor')!r} "
                             f"map ({b}): both must come from the same sensor ({', '.join(SENSORS)})")
    if cam_A is None:
        raise MapFormatError(f"{a}: the map stores no camera; cannot verify places")
    if cam_B is not None and (abs(cam_A.fx - cam_B.fx) > 1e-3 * cam_A.fx or cam_A.width != cam_B.width
                              or cam_A.height != cam_B.height):
        raise MapFormatError(f"cannot merge maps of different cameras: {a} has fx {cam_A.fx:.1f} {cam_A.width}x"
                             f"{cam_A.height}, {b} fx {cam_B.fx:.1f} {cam_B.width}x{cam_B.height}")
    run_dir = open_run_dir(out, inputs=inputs)
    try:
        result = merge_maps(map_A, db_A, map_B, db_B, cam_A, sensor, cfg,
                            options=options, source_b=str(b.resolve()))
        merged = result.map
        meta = dict(meta_A)
        meta["merged"] = list(meta_A.get("merged", [])) + [{
            "a": str(a.resolve()), "b": str(b.resolve()), "S_a_b": result.stats["S_a_b"],
            "seam_keyframes": result.stats["seam_keyframes"]}]
        result.stats["outputs"] = write_map_outputs(out, merged, camera=cam_A, database=result.database, metadata=meta)
        kfs = sorted((k for k in merged.keyframes.values() if not k.bad), key=lambda k: (k.timestamp, k.id))
        # overlapping inputs may both hold a keyframe of one frame: TUM has one pose per time, A's wins
        kfs = [k for i, k in enumerate(kfs) if i == 0 or k.timestamp != kfs[i - 1].timestamp]
        traj = Trajectory(np.array([k.timestamp for k in kfs], float), np.stack([k.T_world_cam for k in kfs]))
        with atomic_path(out / "keyframes.txt") as tmp:
            write_tum(tmp, traj)
        _merge_figure(out / "merge.png", result, sensor)
        if isinstance(config, (str, Path)) and Path(config).is_file():
            with atomic_path(out / "config.yaml") as tmp:
                shutil.copyfile(config, tmp)
        result.stats.update({**paths, "sensor": sensor, "good_keyframes": len(kfs),
                             "points": int(merged.points.n_alive)})
        write_stats(out, result.stats)
    except BaseException as exc:  # stopped (SIGTERM, Ctrl-C) or failed: stats.json with the error, as a run's
        write_error_stats(out, exc, {**paths, "sensor": sensor})
        run_dir.release()
        raise
    run_dir.finish()
    result.output_dir = out
    return result
