"""4-DoF pose-graph optimization (position + yaw) for gravity-aligned maps (visual-inertial SLAM).

In a gravity-aligned world (z up) roll and pitch of every keyframe are observed by the IMU; a loop
correction or a segment join may only move the keyframes by a rotation about the world z axis and a
translation (Qin et al., "VINS-Mono", T-RO 2018, sec. VIII-C, eq. 26; Campos et al., "ORB-SLAM3",
T-RO 2021, sec. VI-C: ``Optimizer::OptimizeEssentialGraph4DoF``).

Parametrization. Node ``k`` has its initial pose ``T_k = [R_k, t_k]``; the optimized pose is

    T_k(theta_k, p_k) = [Rz(theta_k) R_k, p_k]

with ``theta_k`` (yaw change, about world z) and ``p_k`` (the camera centre) free and the tilt
``R_k`` carried unchanged, so every camera keeps its gravity direction ``R^T e_z`` exactly. Write
``Y_k = [Rz(theta_k), p_k]`` (a pose whose rotation is a yaw only); then ``T_k = Y_k [R_k, 0]`` and an
edge measurement ``Z_ij ~ T_i^-1 T_j`` becomes, in the yaw-only frames,

    Y_i^-1 Y_j = [R_i, 0] Z_ij [R_j, 0]^-1 = [Rz(dtheta_ij), dp_ij],

a yaw ``dtheta_ij`` (the z-rotation nearest to ``R_i R_ij R_j^T``: exact for a gravity-consistent
measurement) and a translation ``dp_ij = R_i t_ij``. Its residual is VINS-Mono's 4-DoF residual
(``R_i^-1 (p_j - p_i) - t_ij`` and the yaw difference; rotating the translation residual by the
fixed ``R_i`` leaves its norm unchanged under an isotropic translation sigma). Because
``Rz(theta_i)^T`` leaves the z axis alone the problem splits exactly into

* a planar pose graph over ``(x, y, theta)``: GTSAM ``Pose2`` nodes, ``BetweenFactorPose2``;
* a linear chain over ``z``: ``BetweenFactorDouble`` (``z_j - z_i = dp_ij.z``),

solved together by one Levenberg-Marquardt run. Why this rather than ``Pose3`` nodes with a strong
roll/pitch prior: the prior only approximates a fixed tilt (a stiff prior trades exactness for
conditioning), while here roll and pitch are not variables at all, every factor is a stock GTSAM
factor (no per-factor Python callback), and the yaw/position split is the one VINS-Mono uses.
Fixed nodes are ``NonlinearEqualityPose2`` in the plane; their ``z`` is no variable (edges to them
become ``PriorFactorDouble`` on the other end), so they stay bit-exact.

Edge noise: the default sigmas of :class:`PoseGraphConfig` (``default_sigma_rotation`` for yaw,
``default_sigma_translation`` for x, y and z), optionally weighted by a scalar information.
"""
from __future__ import annotations

import logging
import time
from typing import Iterable, Sequence

import numpy as np

from vslam.errors import GeometryError
from vslam.map.config import PoseGraphConfig
from vslam.map.pose_graph import PoseGraphResult, _checked_edge, nearest_rotations, solve_lm

LOG = logging.getLogger(__name__)

# COLAMD, not the SE(3) graph's METIS: the problem is two disconnected components (the plane and
# the z chain), and GTSAM's METIS ordering crashes (segmentation fault) on such a graph when a
# component is small (two fixed nodes around one free one). Pose2 + scalar blocks are cheap to
# eliminate either way: 151 nodes, 1123 edges solve in 0.18 s (the SE(3) graph with METIS: 0.39 s;
# measured on a loaded 2-core machine).
ELIMINATION_ORDERING_4DOF = "COLAMD"


def yaw_of(R: np.ndarray) -> float:
    """Angle of the rotation about z nearest to ``R (3, 3)`` (Frobenius): ``atan2(R10 - R01, R00 + R11)``."""
    R = np.asarray(R, dtype=float)
    return float(np.arctan2(R[1, 0] - R[0, 1], R[0, 0] + R[1, 1]))


def rot_z(theta: float) -> np.ndarray:
    """``Rz(theta)``, ``(3, 3)``."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def yaw_translation(T_a_b: np.ndarray) -> np.ndarray:
    """The 4-DoF part of a rigid (or Sim(3)) transform ``T_a_b (4, 4)``: ``[Rz(yaw), t]`` with the
    yaw of its rotation (:func:`yaw_of`, the scale divided out) and its translation kept."""
    T = np.asarray(T_a_b, dtype=float)
    s = float(np.cbrt(np.linalg.det(T[:3, :3])))
    out = np.eye(4)
    out[:3, :3] = rot_z(yaw_of(T[:3, :3] / s))
    out[:3, 3] = T[:3, 3]
    return out


def yaw_correction(T_world_cam: np.ndarray, T_world_cam_target: np.ndarray) -> np.ndarray:
    """The world correction ``C = [Rz, t]`` (yaw + translation only) that brings the camera centre of
    ``T_world_cam`` onto ``T_world_cam_target``'s and its heading as near as a yaw can: ``Rz`` is the
    yaw of ``R_target R^T`` and ``t = c_target - Rz c``. The tilt of the camera is unchanged."""
    T, G = np.asarray(T_world_cam, float), np.asarray(T_world_cam_target, float)
    Rg = G[:3, :3] / np.cbrt(np.linalg.det(G[:3, :3]))
    C = np.eye(4)
    C[:3, :3] = rot_z(yaw_of(Rg @ T[:3, :3].T))
    C[:3, 3] = G[:3, 3] - C[:3, :3] @ T[:3, 3]
    return C


def tilt_change_rad(T_before: np.ndarray, T_after: np.ndarray) -> np.ndarray:
    """Per pose, the angle between the gravity direction seen by the camera before and after
    (``R^T e_z``), ``(K,)`` radians; 0 for a yaw + translation move."""
    zb = np.asarray(T_before, float).reshape(-1, 4, 4)[:, 2, :3]  # row 2 of R = R^T e_z
    za = np.asarray(T_after, float).reshape(-1, 4, 4)[:, 2, :3]
    zb = zb / np.linalg.norm(zb, axis=1, keepdims=True)
    za = za / np.linalg.norm(za, axis=1, keepdims=True)
    return np.arctan2(np.linalg.norm(np.cross(zb, za), axis=1), np.sum(zb * za, axis=1))


def _sigmas(info, config: PoseGraphConfig) -> tuple[np.ndarray, float]:
    """``(Pose2 sigmas (x, y, theta), z sigma)`` of an edge with scalar / no information."""
    w = 1.0
    if info is not None:
        if np.ndim(info) != 0:
            raise GeometryError("4-DoF pose-graph edges take a scalar information weight (or none), "
                                f"got an array of shape {np.shape(info)}")
        w = float(info)
        if not w > 0:
            raise GeometryError(f"4-DoF pose-graph edge information must be > 0, got {w}")
    st, sr = config.default_sigma_translation / np.sqrt(w), config.default_sigma_rotation / np.sqrt(w)
    return np.array([st, st, sr]), float(st)


def build_pose_graph_4dof(T_world_cam: np.ndarray, edges: Iterable[Sequence], fixed: Sequence[int],
                          config: PoseGraphConfig):
    """The GTSAM graph and initial values of :func:`optimize_pose_graph_4dof`: ``Pose2`` keys
    ``X(k)`` (yaw change 0, the camera centre's x, y) and ``double`` keys ``Z(k)`` for the free
    nodes' z. Returns ``(graph, values, n_edges, R (K, 3, 3) the carried rotations)``.

    Raises:
        GeometryError: as :func:`vslam.map.pose_graph.build_pose_graph`; array-valued information.
    """
    import gtsam
    from gtsam.symbol_shorthand import X, Z

    n = len(T_world_cam)
    if n == 0:
        raise GeometryError("pose graph has no nodes")
    if not np.all(np.isfinite(T_world_cam)):
        raise GeometryError("pose graph initial poses contain NaN/inf")
    fixed_set = {int(f) for f in fixed}
    if not fixed_set or min(fixed_set) < 0 or max(fixed_set) >= n:
        raise GeometryError(f"pose graph needs fixed node indices in [0, {n}), got {sorted(fixed_set)}")
    R = np.stack(nearest_rotations(T_world_cam[:, :3, :3]))
    c = T_world_cam[:, :3, 3]
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k in range(n):
        values.insert(X(k), gtsam.Pose2(float(c[k, 0]), float(c[k, 1]), 0.0))
        if k not in fixed_set:
            values.insert(Z(k), float(c[k, 2]))
    checked = [_checked_edge(e, n) for e in edges]
    if not checked:
        raise GeometryError("pose graph has no edges")
    Rz_meas = np.stack(nearest_rotations(np.stack([Zm[:3, :3] for _, _, Zm, _ in checked])))
    cache: dict = {}
    for (i, j, Zm, info), Rm in zip(checked, Rz_meas):
        key = None if info is None else float(info) if np.ndim(info) == 0 else id(info)
        if key not in cache:
            s2, sz = _sigmas(info, config)
            cache[key] = (gtsam.noiseModel.Diagonal.Sigmas(s2), gtsam.noiseModel.Isotropic.Sigma(1, sz))
        m2, mz = cache[key]
        dtheta = yaw_of(R[i] @ Rm @ R[j].T)
        dp = R[i] @ Zm[:3, 3]
        graph.add(gtsam.BetweenFactorPose2(X(i), X(j), gtsam.Pose2(float(dp[0]), float(dp[1]), dtheta), m2))
        fi, fj = i in fixed_set, j in fixed_set
        if fi and fj:
            continue
        if fi:  # z_j = z_i + dz with z_i fixed
            graph.add(gtsam.PriorFactorDouble(Z(j), float(c[i, 2] + dp[2]), mz))
        elif fj:
            graph.add(gtsam.PriorFactorDouble(Z(i), float(c[j, 2] - dp[2]), mz))
        else:
            graph.add(gtsam.BetweenFactorDouble(Z(i), Z(j), float(dp[2]), mz))
    for k in sorted(fixed_set):
        graph.add(gtsam.NonlinearEqualityPose2(X(k), values.atPose2(X(k))))
    return graph, values, len(checked), R


def optimize_pose_graph_4dof(
    T_world_cam: np.ndarray,
    edges: Iterable[Sequence],
    fixed: Sequence[int] = (0,),
    config: PoseGraphConfig | None = None,
) -> PoseGraphResult:
    """Optimize node poses over position and yaw only (module docstring); roll and pitch of every
    node (its gravity direction) are kept exactly.

    Args:
        T_world_cam: ``(K, 4, 4)`` initial rigid poses in a gravity-aligned (z up) world.
        edges: items ``(i, j, T_i_j)`` or ``(i, j, T_i_j, weight)`` (``weight`` a scalar on the
            default information, or None), as :func:`vslam.map.pose_graph.optimize_pose_graph`.
        fixed: node indices held constant (at least one: the gauge of x, y, z and yaw).

    Returns:
        :class:`PoseGraphResult` (``scales`` ones, ``S_world_cam`` = ``T_world_cam``).

    Example:
        >>> T = np.tile(np.eye(4), (3, 1, 1)); T[1, 0, 3] = 1.1; T[2, 0, 3] = 2.3
        >>> step = np.eye(4); step[0, 3] = 1.0
        >>> res = optimize_pose_graph_4dof(T, [(0, 1, step), (1, 2, step), (0, 2, step @ step)])
        >>> np.round(res.T_world_cam[:, 0, 3], 3).tolist()
        [0.0, 1.0, 2.0]
    """
    from gtsam.symbol_shorthand import X, Z

    config = config or PoseGraphConfig()
    t0 = time.perf_counter()
    T_world_cam = np.asarray(T_world_cam, dtype=float).reshape(-1, 4, 4)
    n = len(T_world_cam)
    graph, values, n_edges, R = build_pose_graph_4dof(T_world_cam, edges, fixed, config)
    result, initial_error, final_error, iterations = solve_lm(graph, values, config, ELIMINATION_ORDERING_4DOF)
    T_out = np.tile(np.eye(4), (n, 1, 1))
    fixed_set = {int(f) for f in fixed}
    for k in range(n):
        p = result.atPose2(X(k))
        T_out[k, :3, :3] = rot_z(p.theta()) @ R[k]
        z = T_world_cam[k, 2, 3] if k in fixed_set else result.atDouble(Z(k))
        T_out[k, :3, 3] = [p.x(), p.y(), z]
    for k in fixed_set:  # bit-exact: the equality constraint holds them, no round trip through Pose2
        T_out[k] = T_world_cam[k]
    out = PoseGraphResult(
        T_world_cam=T_out, scales=np.ones(n), S_world_cam=T_out.copy(), initial_error=initial_error,
        final_error=final_error, iterations=iterations, time_s=time.perf_counter() - t0)
    LOG.debug("pose graph (4-DoF, %d nodes, %d edges): error %.4g -> %.4g in %d iterations", n, n_edges,
              out.initial_error, out.final_error, out.iterations)
    return out


def fit_yaw_translation(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares ``[Rz(yaw), t]`` with ``dst ~ Rz src + t`` (``(N, 3)`` each, ``N >= 2``): the
    4-DoF Umeyama/Arun closed form, ``yaw = atan2(sum(a_x b_y - a_y b_x), sum(a_x b_x + a_y b_y))``
    over the centred horizontal coordinates ``a`` (src), ``b`` (dst), ``t = mean(dst) - Rz mean(src)``."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src[:, :2] - mu_s[:2], dst[:, :2] - mu_d[:2]
    yaw = np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    T = np.eye(4)
    T[:3, :3] = rot_z(float(yaw))
    T[:3, 3] = mu_d - T[:3, :3] @ mu_s
    return T


def align_points_4dof(src: np.ndarray, dst: np.ndarray, n_hypotheses: int = 256,
                      seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Robust yaw + translation ``T`` (4x4) with ``dst ~ T src`` between two gravity-aligned worlds,
    and the inlier mask. LMedS (Rousseeuw 1984) over 2-point samples (:func:`fit_yaw_translation`;
    two points fix yaw and translation), inliers within ``2.5 * 1.4826 * median residual`` of the
    best hypothesis (< 50 % outliers), refitted on them. As :func:`vslam.geometry.align.align_points`
    (the SE(3) / Sim(3) one) with the rotation restricted to the vertical axis.

    Raises:
        GeometryError: fewer than 3 finite pairs, or all horizontal positions coincide.
    """
    src, dst = np.asarray(src, float).reshape(-1, 3), np.asarray(dst, float).reshape(-1, 3)
    if len(src) != len(dst) or len(src) < 3 or not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise GeometryError(f"4-DoF alignment needs >= 3 finite point pairs of equal count, got {len(src)}/{len(dst)}")
    if np.ptp(src[:, :2], axis=0).max() < 1e-9:
        raise GeometryError("4-DoF alignment: the points coincide horizontally (yaw unobservable)")
    rng = np.random.default_rng(seed)
    n = len(src)
    best, best_med = None, np.inf
    for _ in range(n_hypotheses):
        i, j = rng.choice(n, 2, replace=False)
        if np.linalg.norm(src[i, :2] - src[j, :2]) < 1e-6:
            continue
        T = fit_yaw_translation(src[[i, j]], dst[[i, j]])
        med = float(np.median(np.sum((src @ T[:3, :3].T + T[:3, 3] - dst) ** 2, axis=1)))
        if med < best_med:
            best, best_med = T, med
    if best is None:
        best = fit_yaw_translation(src, dst)
        best_med = float(np.median(np.sum((src @ best[:3, :3].T + best[:3, 3] - dst) ** 2, axis=1)))
    threshold = 2.5 * 1.4826 * np.sqrt(best_med)
    inliers = np.sqrt(np.sum((src @ best[:3, :3].T + best[:3, 3] - dst) ** 2, axis=1)) <= max(threshold, 1e-12)
    if inliers.sum() >= 2:
        best = fit_yaw_translation(src[inliers], dst[inliers])
    return best, inliers
