"""The reduced camera system as a block-sparse matrix, for large bundle adjustments (issue #26).

:mod:`vslam.backend.schur_lm` eliminates the points and solves ``S dc = bc`` on the cameras. Below
``sparse_min_cameras`` variable cameras it forms ``S`` dense (``6 n_c x 6 n_c``) and factors it by
LAPACK's Cholesky, ``O(n_c^3)`` per solve. Above, :class:`SparseCameraSystem` keeps only the
``6 x 6`` blocks of camera pairs that share a point (the pattern of ``S``, Triggs et al., "Bundle
Adjustment - A Modern Synthesis", 2000, Sec. 6.1-6.3: the reduced system is as sparse as the
covisibility graph) plus the diagonal, and factors it by SuperLU (``scipy.sparse.linalg.splu``) in
symmetric mode with a minimum-degree ordering of ``S + S^T`` and no pivoting (``S`` is symmetric
positive definite once damped): its cost follows the fill of that ordering, not ``n_c^3``.

The blocks are summed by :func:`reduced_camera_blocks`, the loop of
:func:`vslam.backend.schur_kernels.reduced_camera_system` with each ``6 x 6`` product written into its
block instead of the dense matrix: every entry gets the same terms in the same order, so ``S`` is the
dense path's to the bit; only the factorization differs (steps equal to ~1e-13 relative, measured in
``tests/backend/test_schur_sparse.py``). The pattern (:func:`block_pattern`) and the CSC layout of the
full symmetric matrix are built once per problem; each solve gathers the block values into it.
"""
from __future__ import annotations

import logging

import numpy as np
import scipy.sparse
import scipy.sparse.linalg
from numba import njit

from vslam.backend.schur_kernels import add_damped_block, point_terms

LOG = logging.getLogger(__name__)


@njit(cache=True, nogil=True)
def block_pattern(pt_ptr, pt_obs, obs_var, n_c):  # pragma: no cover - compiled
    """Block-CSR pattern of the upper triangle of ``S``: ``row_ptr (n_c + 1,)``, ``cols (nnzb,)``
    sorted per row, the diagonal block first (always present). Camera ``r`` has a block ``(r, c)``,
    ``c > r``, when some point has free observations by both (layout as in
    :func:`vslam.backend.schur_kernels.reduced_camera_system`)."""
    cam_ptr = np.zeros(n_c + 1, np.int64)
    for q in range(pt_obs.shape[0]):
        cam_ptr[obs_var[pt_obs[q]] + 1] += 1
    for c in range(n_c):
        cam_ptr[c + 1] += cam_ptr[c]
    cam_pts = np.empty(pt_obs.shape[0], np.int64)  # each camera's points
    pos = cam_ptr[:-1].copy()
    for p in range(pt_ptr.shape[0] - 1):
        for q in range(pt_ptr[p], pt_ptr[p + 1]):
            c = obs_var[pt_obs[q]]
            cam_pts[pos[c]] = p
            pos[c] += 1
    mark = np.full(n_c, -1, np.int64)
    row_ptr = np.zeros(n_c + 1, np.int64)
    cols = np.empty(0, np.int64)
    for fill in range(2):  # count, then fill
        if fill:
            cols = np.empty(row_ptr[n_c], np.int64)
            mark[:] = -1
        for r in range(n_c):
            mark[r] = r
            n = 1
            if fill:
                cols[row_ptr[r]] = r
            for s in range(cam_ptr[r], cam_ptr[r + 1]):
                p = cam_pts[s]
                for q in range(pt_ptr[p], pt_ptr[p + 1]):
                    c = obs_var[pt_obs[q]]
                    if c > r and mark[c] != r:
                        mark[c] = r
                        if fill:
                            cols[row_ptr[r] + n] = c
                        n += 1
            if fill:
                cols[row_ptr[r]:row_ptr[r + 1]] = np.sort(cols[row_ptr[r]:row_ptr[r + 1]])
            else:
                row_ptr[r + 1] = row_ptr[r] + n
    return row_ptr, cols


@njit(cache=True, nogil=True, inline="always")
def _slot(row_ptr, cols, r, c):  # pragma: no cover - compiled
    """Index of block ``(r, c)``, ``c >= r``, in the pattern (binary search of row ``r``)."""
    lo = row_ptr[r]
    hi = row_ptr[r + 1]
    while lo < hi:
        mid = (lo + hi) // 2
        if cols[mid] < c:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, nogil=True)
def reduced_camera_blocks(Hcp, V, gp, gc, pt_ptr, pt_obs, obs_var, row_ptr, cols, B, bc, Y):  # pragma: no cover - compiled
    """:func:`vslam.backend.schur_kernels.reduced_camera_system` into the blocks ``B (nnzb, 6, 6)`` of
    the upper triangle (pattern ``row_ptr``, ``cols``) instead of a dense ``S``: ``B[slot(r, c), i, j]``
    is ``S[6 r + i, 6 c + j]``, with the same terms in the same order; ``bc`` as there."""
    B[:, :, :] = 0.0
    for i in range(bc.shape[0]):
        bc[i] = gc[i]
    for p in range(pt_ptr.shape[0] - 1):
        q0 = pt_ptr[p]
        k = pt_ptr[p + 1] - q0
        point_terms(Hcp, V, gp, pt_obs, obs_var, q0, k, p, Y, bc)
        for a in range(k):
            ca = obs_var[pt_obs[q0 + a]]
            for b in range(a, k):
                mb = pt_obs[q0 + b]
                cb = obs_var[mb]
                if ca < cb or b == a:
                    s = _slot(row_ptr, cols, ca, cb)
                    for i in range(6):
                        y0 = Y[a, 0, i]
                        y1 = Y[a, 1, i]
                        y2 = Y[a, 2, i]
                        for j in range(6):
                            B[s, i, j] -= y0 * Hcp[mb, 0, j] + y1 * Hcp[mb, 1, j] + y2 * Hcp[mb, 2, j]
                else:  # the transposed block (and both halves when one camera sees the point twice)
                    s = _slot(row_ptr, cols, cb, ca)
                    for i in range(6):
                        for j in range(6):
                            v = Y[a, 0, i] * Hcp[mb, 0, j] + Y[a, 1, i] * Hcp[mb, 1, j] + Y[a, 2, i] * Hcp[mb, 2, j]
                            B[s, j, i] -= v
                            if ca == cb:
                                B[s, i, j] -= v


@njit(cache=True, nogil=True)
def add_damped_diagonal_blocks(B, row_ptr, Hcc, lam):  # pragma: no cover - compiled
    """:func:`vslam.backend.schur_kernels.add_damped_camera_blocks` on the diagonal blocks
    ``B[row_ptr[k]]`` (each row's first block)."""
    for k in range(Hcc.shape[0]):
        add_damped_block(B[row_ptr[k]], Hcc[k], lam)


# The sparse path stays off when the pattern stores more than this share of the n_c^2 blocks: the LU's fill then
# makes it slower than the dense Cholesky. Measured (CPU, one damped solve, 259 cameras, stereo, banded synthetic
# problems): 3 % of the blocks 7.5 vs 49 ms dense, 14 % 61 vs 81 ms, 28 % 161 vs 144 ms, 48 % 383 vs 302 ms; the
# 32-session synthetic fleet's global BA (260 keyframes, 43 %) took 2.12 CPU s sparse vs 1.52 s dense (benchmarks/RESULTS.md).
MAX_DENSITY = 0.25


def sparse_system(pt_ptr: np.ndarray, pt_obs: np.ndarray, obs_var: np.ndarray, n_c: int,
                  max_density: float = MAX_DENSITY) -> SparseCameraSystem | None:
    """The :class:`SparseCameraSystem` of a problem, or None when its pattern holds more than
    ``max_density`` of the ``n_c^2`` blocks (the dense path is faster there)."""
    row_ptr, cols = block_pattern(pt_ptr, pt_obs, obs_var, n_c)
    density = (2 * len(cols) - n_c) / max(n_c * n_c, 1)
    LOG.debug("reduced camera system: %d cameras, %.1f %% of the blocks non-zero: %s", n_c, 100 * density,
              "dense" if density > max_density else "sparse")
    return None if density > max_density else SparseCameraSystem(row_ptr, cols, n_c, density)


class SparseCameraSystem:
    """The pattern of ``S`` (:func:`block_pattern`) for one problem and the CSC layout of the full
    symmetric matrix: ``csc_rows``/``csc_ptr`` the scalar pattern in CSC order, ``src`` each stored
    entry's position in ``B.ravel()`` (a block above the diagonal gives its entries and their transposes)."""

    def __init__(self, row_ptr: np.ndarray, cols: np.ndarray, n_c: int, density: float) -> None:
        self.n_c, self.row_ptr, self.cols, self.density = n_c, row_ptr, cols, density
        nb = len(cols)
        brow = np.repeat(np.arange(n_c), np.diff(row_ptr))
        ii, jj = np.divmod(np.arange(36), 6)
        rows = (6 * brow[:, None] + ii).ravel()
        cols = (6 * cols[:, None] + jj).ravel()
        src = np.arange(36 * nb)
        off = np.repeat(brow != self.cols, 36)
        rows, cols, src = (np.concatenate([rows, cols[off]]), np.concatenate([cols, rows[off]]),
                           np.concatenate([src, src[off]]))
        order = np.lexsort((rows, cols))
        self.csc_rows = rows[order].astype(np.int32)
        self.src = src[order]
        self.csc_ptr = np.zeros(6 * n_c + 1, np.int32)
        np.cumsum(np.bincount(cols, minlength=6 * n_c), out=self.csc_ptr[1:])
        self.B = np.empty((nb, 6, 6))

    def reduce(self, W, V, gp, gc, pt_ptr, pt_obs, obs_var, Y, bc) -> None:
        """``B`` (the upper blocks of ``-W V W^T``) and ``bc``, see :func:`reduced_camera_blocks`."""
        reduced_camera_blocks(W, V, gp, gc, pt_ptr, pt_obs, obs_var, self.row_ptr, self.cols, self.B, bc, Y)

    def solve(self, Hcc: np.ndarray, lam: float, bc: np.ndarray) -> np.ndarray:
        """``(B + blockdiag(Hcc damped))^-1 bc`` by SuperLU (module docstring); dense least squares
        if the factorization fails (as the dense path's fallback when Cholesky does)."""
        add_damped_diagonal_blocks(self.B, self.row_ptr, Hcc, float(lam))
        n = 6 * self.n_c
        S = scipy.sparse.csc_matrix((self.B.reshape(-1)[self.src], self.csc_rows, self.csc_ptr), shape=(n, n))
        try:
            lu = scipy.sparse.linalg.splu(S, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                          options={"SymmetricMode": True})
            dc = lu.solve(bc)
            if np.all(np.isfinite(dc)):
                return dc
        except (RuntimeError, ValueError) as exc:  # singular (or non-finite input)
            LOG.debug("sparse reduced camera system: %s; dense least squares", exc)
        return np.linalg.lstsq(S.toarray(), bc, rcond=None)[0]
