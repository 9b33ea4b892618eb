"""Dense RGB-D alignments between consecutive keyframes as local-BA constraints.

On texture-poor RGB-D views the tracker's pose of a keyframe comes from dense alignment of the
whole depth and grey images to the previous keyframe (:mod:`vslam.frontend.depth_icp`), which is
far more accurate than the few sparse features there (keypoints on object outlines, with ambiguous
depth). A bundle adjustment over those sparse features alone pulls such keyframes back towards
the feature poses. A *link* keeps the dense relative pose in the problem without a new factor type:
sample points ``X_b`` of keyframe b's depth image (camera b) become extra BA points observed by b
at their pixel with their depth and by keyframe a where ``T_a_b X_b`` projects, with the depth it
has there. Each such point is a 3-dof constraint on the relative pose ``T_a_b`` with the same
pixel / virtual-stereo errors as a feature (the "virtual correspondences" encoding of a relative
pose measurement; e.g. the ICP edges of RGB-D SLAM pose graphs, Kerl et al., IROS 2013, written
as correspondences). Points and observations are appended after the real ones and removed from
the result before it is written back (:func:`strip_dense_links`). The link type and the depth
sampling the tracker records them with are in :mod:`vslam.map.dense_links`.

Example:
    >>> problem, n = add_dense_links(problem, links, sigma_px=1.0)  # doctest: +SKIP
    >>> result = local_bundle_adjustment(problem, cfg)  # doctest: +SKIP
    >>> problem, result = strip_dense_links(problem, result, n)  # doctest: +SKIP
"""
from __future__ import annotations

import dataclasses

import numpy as np

from vslam.backend.problem import BAProblem, BAResult
from vslam.map.dense_links import DenseLink


def add_dense_links(problem: BAProblem, links: dict[int, DenseLink], sigma_px: float = 1.0,
                    min_depth: float = 0.1) -> tuple[BAProblem, int]:
    """``problem`` plus the points of every link whose two keyframes are in it (at least one not
    fixed), and the number of points added (0: ``problem`` itself). Point ids are negative. A sample
    enters only if it lies more than ``min_depth`` metres in front of keyframe a (the tracker's
    samples are already in front of b)."""
    kf_ids = problem.kf_ids
    present = set(kf_ids.tolist())
    fixed = set(problem.fixed_kf_ids.tolist())
    K = problem.camera.K
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    T_by_id = {int(k): T for k, T in zip(kf_ids, problem.T_world_cam)}
    X, ids_all, o_kf, o_pt, o_uv, o_d = [], [], [], [], [], []
    next_id = -1
    for b, link in links.items():
        a = link.prev_kf_id
        if b not in present or a not in present or (a in fixed and b in fixed) or len(link.depth) == 0:
            continue
        z = link.depth
        Xb = np.column_stack([(link.uv[:, 0] - cx) / fx * z, (link.uv[:, 1] - cy) / fy * z, z])
        Xa = Xb @ link.T_prev_cur[:3, :3].T + link.T_prev_cur[:3, 3]
        front = Xa[:, 2] > min_depth
        if not front.any():
            continue
        Xb, Xa, uvb, zb = Xb[front], Xa[front], link.uv[front], z[front]
        n = len(Xb)
        uva = np.column_stack([fx * Xa[:, 0] / Xa[:, 2] + cx, fy * Xa[:, 1] / Xa[:, 2] + cy])
        ids = np.arange(next_id, next_id - n, -1, dtype=np.int64)
        next_id -= n
        T_wb = T_by_id[b]
        X.append(Xb @ T_wb[:3, :3].T + T_wb[:3, 3])
        ids_all.append(ids)
        o_kf += [np.full(n, b, np.int64), np.full(n, a, np.int64)]
        o_pt += [ids, ids]
        o_uv += [uvb, uva]
        o_d += [zb, Xa[:, 2]]
    if not X:
        return problem, 0
    X_new = np.concatenate(X)
    kf_new, pt_new = np.concatenate(o_kf), np.concatenate(o_pt)
    m = len(kf_new)
    out = BAProblem(
        camera=problem.camera, kf_ids=problem.kf_ids, T_world_cam=problem.T_world_cam,
        pt_ids=np.concatenate([problem.pt_ids] + ids_all),
        X_world=np.concatenate([problem.X_world, X_new]),
        obs_kf=np.concatenate([problem.obs_kf, kf_new]), obs_pt=np.concatenate([problem.obs_pt, pt_new]),
        obs_uv=np.concatenate([problem.obs_uv, np.concatenate(o_uv)]),
        obs_sigma=np.concatenate([problem.obs_sigma, np.full(m, float(sigma_px))]),
        obs_u_right=np.concatenate([problem.obs_u_right, np.full(m, np.nan)]),
        obs_depth=np.concatenate([problem.obs_depth, np.concatenate(o_d)]),
        fixed_kf_ids=problem.fixed_kf_ids,
    )
    return out, len(X_new)


def strip_dense_links(problem: BAProblem, result: BAResult, n_points: int) -> tuple[BAProblem, BAResult]:
    """The problem and result without the last ``n_points`` points (the links') and their
    observations (which come after the real ones)."""
    if n_points == 0:
        return problem, result
    p = len(problem.pt_ids) - n_points
    m = len(problem.obs_pt) - 2 * n_points  # two observations per link point
    real = dataclasses.replace(
        problem, pt_ids=problem.pt_ids[:p], X_world=problem.X_world[:p], obs_kf=problem.obs_kf[:m],
        obs_pt=problem.obs_pt[:m], obs_uv=problem.obs_uv[:m], obs_sigma=problem.obs_sigma[:m],
        obs_u_right=problem.obs_u_right[:m], obs_depth=problem.obs_depth[:m],
    )
    res = dataclasses.replace(result, pt_ids=result.pt_ids[:p], X_world=result.X_world[:p],
                              inlier_mask=result.inlier_mask[:m])
    return real, res
