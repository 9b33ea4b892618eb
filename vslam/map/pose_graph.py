"""SE(3) and Sim(3) pose-graph optimization with GTSAM (loop closing's essential-graph step).

Nodes are the keyframe poses ``T_world_cam`` (Sim(3): ``S_world_cam = [s R, t; 0, 1]``, mapping
``X_world = s R X_cam + t``). An edge ``(i, j, T_i_j)`` measures the pose of node ``j`` in the frame
of node ``i``, ``T_i_j = T_world_i^-1 T_world_j`` (Sim(3): ``S_i_j``, whose scale is the ratio of
the local map scales, e.g. the scale of a monocular loop closure). The cost is (Kuemmerle et al.,
"g2o", ICRA 2011; Strasdat et al., "Scale drift-aware large scale monocular SLAM", RSS 2010)

    sum_edges || Log(Z_ij^-1 X_i^-1 X_j) ||^2_{Omega_ij}

with ``BetweenFactorPose3`` / ``BetweenFactorSimilarity3``, fixed nodes held by
``NonlinearEquality``. Tangent order is GTSAM's: ``(rotation, translation)`` for SE(3) and
``(rotation, translation, log scale)`` for Sim(3); an edge ``information`` matrix uses that order.
ORB-SLAM2 (Sec. VI-D) optimizes the essential graph (spanning tree, covisibility >= 100, loop edges)
this way and then maps every point with its reference keyframe's correction.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from vslam.map.config import PoseGraphConfig
from vslam.errors import GeometryError
from vslam.geometry.lie import make_sim3, sim3_decompose

LOG = logging.getLogger(__name__)

# GTSAM's default COLAMD ordering makes the multifrontal Cholesky of a densely covisible essential
# graph slow: 7-Scenes redkitchen's loop (151 keyframes, 3484 edges) eliminates in 0.49 s per LM
# iteration with COLAMD and 0.02 s with METIS (nested dissection), which gives the same poses to
# 2e-16 (1.7 s -> 0.08 s for the solve).
ELIMINATION_ORDERING = "METIS"


@dataclass
class PoseGraphResult:
    """Optimized nodes: rigid ``T_world_cam (K, 4, 4)``, ``scales (K,)`` (ones for SE(3)) and the
    similarity ``S_world_cam (K, 4, 4) = [s R, t; 0, 1]``; errors are GTSAM's ``0.5 sum ||e||^2_Omega``."""

    T_world_cam: np.ndarray
    scales: np.ndarray
    S_world_cam: np.ndarray
    initial_error: float
    final_error: float
    iterations: int
    time_s: float


def load_solver() -> float:
    """Import GTSAM (the solver of :func:`optimize_pose_graph`) now; returns the milliseconds it took.

    Its first import costs ~0.3 s of CPU: a loop closer calls this at start-up so that the first
    loop correction (inline in the tracking thread in deterministic mode) does not pay it."""
    t0 = time.perf_counter()
    import gtsam  # noqa: F401

    return 1e3 * (time.perf_counter() - t0)


def _to_gtsam_sim3(S: np.ndarray):
    import gtsam

    s, R, t = sim3_decompose(S)
    U, _, Vt = np.linalg.svd(R)
    return gtsam.Similarity3(gtsam.Rot3(U @ Vt), t / s, s)  # GTSAM maps p -> s (R p + t_g)


def _from_gtsam_sim3(S) -> np.ndarray:
    return make_sim3(S.scale(), S.rotation().matrix(), S.scale() * np.asarray(S.translation()))


def _noise(info: np.ndarray | float | None, dim: int, config: PoseGraphConfig):
    import gtsam

    if info is None:
        sig = [config.default_sigma_rotation] * 3 + [config.default_sigma_translation] * 3
        if dim == 7:
            sig.append(config.default_sigma_scale)
        return gtsam.noiseModel.Diagonal.Sigmas(np.array(sig))
    info = np.asarray(info, dtype=float)
    if info.ndim == 0:  # a scalar weight multiplies the default information
        base = np.array([config.default_sigma_rotation] * 3 + [config.default_sigma_translation] * 3
                        + ([config.default_sigma_scale] if dim == 7 else []))
        return gtsam.noiseModel.Diagonal.Sigmas(base / np.sqrt(float(info)))
    if info.shape != (dim, dim):
        raise GeometryError(f"pose-graph edge information must be ({dim}, {dim}), got {info.shape}")
    return gtsam.noiseModel.Gaussian.Information(info)


def optimize_pose_graph(
    T_world_cam: np.ndarray,
    edges: Iterable[Sequence],
    fixed: Sequence[int] = (0,),
    sim3: bool = False,
    config: PoseGraphConfig | None = None,
) -> PoseGraphResult:
    """Optimize node poses given relative-pose edges.

    Args:
        T_world_cam: ``(K, 4, 4)`` initial poses (rigid; Sim(3) starts every scale at 1).
        edges: items ``(i, j, T_i_j)`` or ``(i, j, T_i_j, information)`` with node indices ``i, j``,
            ``T_i_j`` ``(4, 4)`` (a Sim(3) matrix ``[s R, t; 0, 1]`` when ``sim3``), ``information``
            a ``(6, 6)`` / ``(7, 7)`` matrix in GTSAM tangent order, a scalar weight on the
            default sigmas of ``config``, or ``None``.
        fixed: node indices held constant (the gauge; at least one).
        sim3: optimize Sim(3) nodes (monocular scale drift) instead of SE(3).

    Returns:
        :class:`PoseGraphResult`.

    Example:
        >>> T = np.tile(np.eye(4), (3, 1, 1)); T[1, 0, 3] = 1.1; T[2, 0, 3] = 2.3
        >>> step = np.eye(4); step[0, 3] = 1.0
        >>> edges = [(0, 1, step), (1, 2, step), (0, 2, step @ step)]
        >>> res = optimize_pose_graph(T, edges)
        >>> np.round(res.T_world_cam[:, 0, 3], 3).tolist()
        [0.0, 1.0, 2.0]
    """
    import gtsam

    config = config or PoseGraphConfig()
    t0 = time.perf_counter()
    T_world_cam = np.asarray(T_world_cam, dtype=float).reshape(-1, 4, 4)
    n = len(T_world_cam)
    graph, values, n_edges = build_pose_graph(T_world_cam, edges, fixed, sim3, config)
    result, initial_error, final_error, iterations = solve_lm(graph, values, config, ELIMINATION_ORDERING)
    S_out = _read_nodes(result, n, sim3)
    scales = np.cbrt(np.linalg.det(S_out[:, :3, :3]))
    T_out = S_out.copy()
    T_out[:, :3, :3] /= scales[:, None, None]
    out = PoseGraphResult(
        T_world_cam=T_out, scales=scales, S_world_cam=S_out, initial_error=initial_error,
        final_error=final_error, iterations=iterations, time_s=time.perf_counter() - t0,
    )
    LOG.debug("pose graph (%s, %d nodes, %d edges): error %.4g -> %.4g in %d iterations",
              "Sim3" if sim3 else "SE3", n, n_edges, out.initial_error, out.final_error, out.iterations)
    return out


def solve_lm(graph, values, config: PoseGraphConfig, ordering: str) -> tuple[object, float, float, int]:
    """GTSAM Levenberg-Marquardt on a pose graph with ``config``'s iteration limit and relative
    tolerance and the elimination ``ordering`` (``METIS`` / ``COLAMD``). Returns ``(values,
    initial_error, final_error, iterations)``."""
    import gtsam

    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(config.max_iterations)
    params.setRelativeErrorTol(config.relative_tolerance)
    params.setOrderingType(ordering)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    initial_error = float(graph.error(values))
    result = optimizer.optimize()
    return result, initial_error, float(graph.error(result)), int(optimizer.iterations())


def build_pose_graph(T_world_cam: np.ndarray, edges: Iterable[Sequence], fixed: Sequence[int], sim3: bool,
                     config: PoseGraphConfig):
    """The GTSAM factor graph and initial values of :func:`optimize_pose_graph` (arguments as
    there, ``T_world_cam (K, 4, 4)``): one ``Pose3`` / ``Similarity3`` value per node, a between
    factor per edge, a ``NonlinearEquality`` per fixed node. Returns ``(graph, values, n_edges)``.

    Raises:
        GeometryError: no nodes, NaN/inf poses, fixed indices out of range, a malformed edge, no edges.
    """
    import gtsam

    n = len(T_world_cam)
    if n == 0:
        raise GeometryError("pose graph has no nodes")
    if not np.all(np.isfinite(T_world_cam)):
        raise GeometryError("pose graph initial poses contain NaN/inf")
    fixed = sorted({int(f) for f in fixed})
    if not fixed or min(fixed) < 0 or max(fixed) >= n:
        raise GeometryError(f"pose graph needs fixed node indices in [0, {n}), got {fixed}")
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    dim = 7 if sim3 else 6
    if sim3:
        for k in range(n):
            values.insert(k, _to_gtsam_sim3(T_world_cam[k]))
    else:
        R = nearest_rotations(T_world_cam[:, :3, :3])
        for k in range(n):
            values.insert(k, gtsam.Pose3(gtsam.Rot3(R[k]), T_world_cam[k, :3, 3]))
    # every edge checked (in order) with its noise model (shared by the edges of the same default or
    # scalar information), then the SE(3) measurements' rotations in one batched SVD
    checked, models, cache = [], [], {}
    for e in edges:
        i, j, Z, info = _checked_edge(e, n)
        if info is None or np.ndim(info) == 0:  # the default sigmas, or them weighted by a scalar
            key = None if info is None else float(info)
            if key not in cache:
                cache[key] = _noise(info, dim, config)
            models.append(cache[key])
        else:
            models.append(_noise(info, dim, config))
        checked.append((i, j, Z))
    if not checked:
        raise GeometryError("pose graph has no edges")
    if sim3:
        for (i, j, Z), model in zip(checked, models):
            graph.add(gtsam.BetweenFactorSimilarity3(i, j, _to_gtsam_sim3(Z), model))
    else:
        R = nearest_rotations(np.stack([Z[:3, :3] for _, _, Z in checked]))
        for (i, j, Z), model, Rz in zip(checked, models, R):
            graph.add(gtsam.BetweenFactorPose3(i, j, gtsam.Pose3(gtsam.Rot3(Rz), Z[:3, 3]), model))
    n_edges = len(checked)
    for k in fixed:
        if sim3:
            graph.add(gtsam.NonlinearEqualitySimilarity3(k, values.atSimilarity3(k)))
        else:
            graph.add(gtsam.NonlinearEqualityPose3(k, values.atPose3(k)))
    return graph, values, n_edges


def _checked_edge(e: Sequence, n: int) -> tuple[int, int, np.ndarray, object]:
    """``(i, j, T_i_j, information or None)`` of one edge ``(i, j, T_i_j[, information])`` after checking it."""
    if len(e) not in (3, 4):
        raise GeometryError(f"pose-graph edge must be (i, j, T_i_j[, information]), got {len(e)} items")
    i, j, Z = int(e[0]), int(e[1]), np.asarray(e[2], dtype=float)
    info = e[3] if len(e) == 4 else None
    if not (0 <= i < n and 0 <= j < n) or i == j:
        raise GeometryError(f"pose-graph edge ({i}, {j}) references nodes outside [0, {n}) or a self-loop")
    if Z.shape != (4, 4) or not np.all(np.isfinite(Z)):
        raise GeometryError(f"pose-graph edge ({i}, {j}) measurement must be a finite 4x4 matrix")
    return i, j, Z, info


def nearest_rotations(M: np.ndarray) -> list[np.ndarray]:
    """The rotation nearest to each ``M[k] (3, 3)`` (Frobenius norm): ``U V^T`` of its SVD
    ``U S V^T`` (Higham 1989). One batched SVD (the same LAPACK call per matrix as one at a time,
    ~10x less overhead over thousands of pose-graph edges); each product ``U @ V^T`` a separate 3 x 3
    matmul, as before."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float).reshape(-1, 3, 3))
    return [u @ vt for u, vt in zip(U, Vt)]


def _read_nodes(result, n: int, sim3: bool) -> np.ndarray:
    """The optimized nodes as ``S_world_cam (n, 4, 4)`` (rigid poses for SE(3))."""
    S_out = np.empty((n, 4, 4))
    for k in range(n):
        if sim3:
            S_out[k] = _from_gtsam_sim3(result.atSimilarity3(k))
        else:
            S_out[k] = result.atPose3(k).matrix()
    return S_out


def correct_points(X_world: np.ndarray, ref_node: np.ndarray, T_world_cam_before: np.ndarray,
                   S_world_cam_after: np.ndarray) -> np.ndarray:
    """Move points with their reference keyframe's correction (ORB-SLAM2 loop correction, Sec. VII-B).

    ``X_new = S_world_cam_after[k] (T_world_cam_before[k]^-1 X)`` with ``k = ref_node`` of each point:
    the point keeps its coordinates in its reference camera, which now sits (and, for Sim(3), is
    scaled) as optimized. ``X_world (N, 3)``, ``ref_node (N,)`` node indices, poses ``(K, 4, 4)``
    (``S_world_cam_after`` may be :attr:`PoseGraphResult.S_world_cam` or rigid poses).
    """
    X_world = np.asarray(X_world, dtype=float).reshape(-1, 3)
    ref = np.asarray(ref_node, dtype=np.int64).reshape(-1)
    Tb = np.asarray(T_world_cam_before, dtype=float)
    Sa = np.asarray(S_world_cam_after, dtype=float)
    if len(ref) != len(X_world) or (len(ref) and (ref.min() < 0 or ref.max() >= len(Tb) or len(Tb) != len(Sa))):
        raise GeometryError("correct_points: ref_node must index the (equal-length) pose arrays, one per point")
    R = Tb[ref, :3, :3]
    X_cam = np.einsum("nji,nj->ni", R, X_world - Tb[ref, :3, 3])
    return np.einsum("nij,nj->ni", Sa[ref, :3, :3], X_cam) + Sa[ref, :3, 3]
