"""Local mapping of the inertial sensors once the IMU is initialized: the local BA becomes a
visual-inertial one (:func:`vslam.backend.inertial_ba.inertial_bundle_adjustment`), and full VI-BAs
run after the initialization and a few seconds later (ORB-SLAM3's ``LocalMapping``: after
``InitializeIMU``, then at 5 s and 15 s).

Window (ORB-SLAM3 ``LocalInertialBA``): the visual local BA's problem (the newest keyframes and the
covisible ones optimized, the keyframes outside the window that see its points fixed; built by
:class:`vslam.backend.local_problem.LocalProblemBuilder`) plus the IMU chain: the run of the
segment's newest keyframes (in time) that are variables of the problem, each with its state (pose,
velocity, biases), and the keyframe just before them, its state held fixed (the prior at the
window's old end). Consecutive keyframes further apart than :data:`MAX_INTERVAL_S` get no IMU factor.

Per keyframe the state is stored in ``kf.extra`` (the contract maps and merging rely on):
``kf.extra["imu_velocity"]`` ``(3,)`` float64, world frame, m/s, and ``kf.extra["imu_bias"]``
``(6,)`` float64, gyro (rad/s) then accelerometer (m/s^2) bias, IMU frame.

RGB-D (``rgbd-inertial``) keeps the visual local BA (the full VI-BAs run): on the renderer's RGB-D
IMU sequence (tests/cli/test_run_imu.py, 75 frames of a fast loop, up to 3.4 rad/s) the local VI-BA
took the SE(3) ATE from 0.0187 to 0.0311 m (plain RGB-D 0.0175): the full VI-BA after the
initialization put the gyro bias 0.010 rad/s off (the visual rotations of that sequence err in
proportion to the rotation rate, which a window of 1 s cannot tell from a bias), and the local VI-BA
then holds every rotation to it. No real RGB-D + IMU data is at hand to decide otherwise.

Modes: deterministic and realtime run the VI-BA where the visual BA ran (:meth:`process`); parallel
mode in its worker, a thread or a child process (``backend.parallel_worker=process``, the default of
parallel mode: the job carries the chain, whose GTSAM preintegrations pickle, and ``T_imu_cam``, and
the child solves it with :func:`solve_inertial_job`).
"""
from __future__ import annotations

import logging
import time

import numpy as np

from vslam.backend.inertial_ba import ImuChain, InertialBAResult, inertial_bundle_adjustment
from vslam.backend.local_mapping import LocalMapper, solve_job
from vslam.backend.local_problem import segment_keyframes
from vslam.errors import DatasetError
from vslam.inertial import ImuBias, make_params, preintegrate
from vslam.map.keyframe import KeyFrame

log = logging.getLogger(__name__)

#: No IMU factor between keyframes further apart (s): a long gap is a lost stretch whose
#: preintegration (biases held over it) is no longer worth a constraint. The IMU-only stretch of
#: tests/test_inertial_blackout.py (0.5 s black) stays well inside.
MAX_INTERVAL_S = 3.0
#: Zero-mean bias prior on the first keyframe of a full VI-BA (rad/s, m/s^2): ORB-SLAM3's first
#: ``FullInertialBA`` after ``InitializeIMU`` (priorG 1e2 -> 0.1; priorA 1e5 -> 3.2e-3 stereo;
#: monocular 1e10 -> 1e-5, as in the initialization). ORB-SLAM3's refinements release the monocular
#: one (``InitializeIMU(1, 1e5)``: 1 and 3.2e-3); measured on MH_01 80 frames with the refinement
#: moved to 3 s (it runs at 5 s): mono-inertial SE(3) ATE 0.00283 m keeping these, 0.00301 m with
#: ORB-SLAM3's (its b_a went to (-0.073, 0.006, 0.043), ground truth (-0.025, 0.137, 0.076)): the
#: refinements keep them.
FULL_BA_PRIOR = {"stereo": (0.1, 1e5 ** -0.5), "mono": (0.1, 1e-5)}
#: A local VI-BA reuses the preintegration of a keyframe interval it built before (the interval's
#: samples are the same) while the interval's start bias moved less than this (rad/s, m/s^2, each
#: component) since: GTSAM's ``CombinedImuFactor`` corrects the deltas to first order in the bias
#: change (Forster et al. T-RO 2017, eq. 44), as ORB-SLAM3's local inertial BA always does (it never
#: re-integrates there). Each local VI-BA re-integrated ~8 intervals before, 1 now (MH_01 80 frames).
REUSE_BIAS_TOL = (1e-3, 1e-2)


def keyframe_state(kf: KeyFrame) -> tuple[np.ndarray, np.ndarray] | None:
    """``(velocity (3,), bias (6,))`` stored on ``kf`` (module docstring), or None."""
    v, b = kf.extra.get("imu_velocity"), kf.extra.get("imu_bias")
    if v is None or b is None:
        return None
    return np.asarray(v, float).reshape(3), np.asarray(b, float).reshape(6)


def store_state(kf: KeyFrame, velocity: np.ndarray, bias: np.ndarray) -> None:
    """Write the ``imu_velocity`` / ``imu_bias`` contract of the module docstring."""
    kf.extra["imu_velocity"] = np.array(velocity, dtype=np.float64).reshape(3)
    kf.extra["imu_bias"] = np.array(bias, dtype=np.float64).reshape(6)


def build_chain(kfs: list[KeyFrame], imu, calib, params=None, free_first: bool = False,
                bias_prior: tuple[float, float] | None = None, cache: dict | None = None) -> ImuChain | None:
    """The :class:`ImuChain` of keyframes ``kfs`` (time order), preintegrated at each interval's
    start bias. A keyframe without a stored state takes its neighbour's bias and the velocity of
    its camera centre's finite difference (the first VI-BA after a keyframe made before the
    tracker had a state). ``cache``: ``{(id_i, id_j): (t0, t1, bias (6,), pim)}`` of earlier calls,
    reused within :data:`REUSE_BIAS_TOL` and replaced by this call's intervals."""
    if len(kfs) < 2:
        return None
    params = make_params(calib) if params is None else params
    n = len(kfs)
    V, B = np.zeros((n, 3)), np.full((n, 6), np.nan)
    known = np.zeros(n, bool)
    for i, kf in enumerate(kfs):
        s = keyframe_state(kf)
        if s is not None:
            V[i], B[i] = s
            known[i] = True
    if not known.any():
        return None
    for i in np.flatnonzero(~known):
        j = int(np.flatnonzero(known)[np.argmin(np.abs(np.flatnonzero(known) - i))])
        B[i] = B[j]
        a, b = max(i - 1, 0), min(i + 1, n - 1)
        dt = kfs[b].timestamp - kfs[a].timestamp
        V[i] = (kfs[b].T_world_cam[:3, 3] - kfs[a].T_world_cam[:3, 3]) / dt if dt > 0 else V[j]
    pims = [_interval_pim(kfs[i], kfs[i + 1], B[i], imu, calib, params, cache) for i in range(n - 1)]
    if cache is not None:
        keep = {(kfs[i].id, kfs[i + 1].id) for i in range(n - 1)}
        for key in [k for k in cache if k not in keep]:
            del cache[key]
    free = None
    if free_first:
        free = np.zeros(n, bool)
        free[0] = True
    return ImuChain(np.array([k.id for k in kfs], np.int64), np.stack([k.T_world_cam for k in kfs]), V, B, pims,
                    bias_prior, free)


def _interval_pim(kf_i: KeyFrame, kf_j: KeyFrame, bias: np.ndarray, imu, calib, params, cache: dict | None):
    """The preintegration between two consecutive keyframes at ``bias (6,)`` (None: no IMU factor),
    from ``cache`` when it holds the same interval at a bias within :data:`REUSE_BIAS_TOL`."""
    t0, t1 = calib.imu_time(kf_i.timestamp), calib.imu_time(kf_j.timestamp)
    if not 0 < t1 - t0 <= MAX_INTERVAL_S:
        return None
    hit = None if cache is None else cache.get((kf_i.id, kf_j.id))
    if hit is not None and hit[0] == t0 and hit[1] == t1 and np.abs(hit[2][:3] - bias[:3]).max() <= REUSE_BIAS_TOL[0] \
            and np.abs(hit[2][3:] - bias[3:]).max() <= REUSE_BIAS_TOL[1]:
        return hit[3]
    try:
        pim = preintegrate(imu, t0, t1, params, ImuBias(bias[:3], bias[3:]))
    except DatasetError as exc:
        log.debug("no IMU factor between keyframes %d and %d: %s", kf_i.id, kf_j.id, exc)
        return None
    if cache is not None:
        cache[(kf_i.id, kf_j.id)] = (t0, t1, np.array(bias, float), pim)
    return pim


def solve_inertial_job(config, job):
    """A local BA job's solve (in the mapper's thread, or in the parallel mode's worker): visual-inertial
    when it carries a chain (:meth:`InertialLocalMapper._prepare`), else :func:`solve_job`; a failure
    comes back as its message (the map stays as it is)."""
    chain = getattr(job, "chain", None)
    if chain is None:
        return solve_job(config, job)
    try:
        return inertial_bundle_adjustment(job.problem, chain, job.T_imu_cam, config)
    except Exception as exc:
        return f"{type(exc).__name__}: {exc}"


class InertialLocalMapper(LocalMapper):
    """:class:`LocalMapper` whose local BA is visual-inertial once ``inertial`` (an
    :class:`vslam.backend.inertial_mapping.InertialMapping`, set by the System) is initialized.
    ``state_listeners``: called as ``cb(kf_ids)`` after keyframe states were written."""

    job_solver = staticmethod(solve_inertial_job)

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.inertial = None
        self.state_listeners: list = []
        self._params = None
        self._pims: dict = {}  # the local chain's preintegrations, reused (build_chain's cache)
        self.counts.update({"vi_ba_calls": 0, "vi_ba_full_calls": 0})
        # a session continuing a loaded map chains only its own keyframes (ids from here on): the
        # loaded ones were taken with another recording's IMU (vslam.imu_from_map)
        self.first_session_kf = 0
        self.full_ba_results: list[dict] = []
        # ids of the keyframes whose stored state a VI-BA estimated (tracking anchors its inertial pose
        # optimization on them); None when the local BA cannot be visual-inertial (RGB-D)
        self.estimated: set[int] | None = None if not self._vi_local else set()

    @property
    def _vi_local(self) -> bool:
        """Whether the local BA becomes visual-inertial (module docstring: not for RGB-D)."""
        return self.sensor != "rgbd"

    @property
    def active(self) -> bool:
        return self.inertial is not None and self.inertial.initialized

    def _imu_params(self):
        if self._params is None:
            self._params = make_params(self.inertial.calib)
        return self._params

    # ------------------------------------------------------------------ local VI-BA
    def _prepare(self, kf_id: int):
        job = super()._prepare(kf_id)
        if job is not None and self.active and self._vi_local:
            with self.lock:
                job.chain = self._local_chain(job.problem, kf_id)
                job.T_imu_cam = self.inertial.calib.T_imu_cam
        return job

    def _local_chain(self, problem, kf_id: int) -> ImuChain | None:
        """The newest keyframes of the segment that are variables of ``problem`` (a run in time) and
        the one before them (module docstring); this session's keyframes only (:attr:`first_session_kf`)."""
        kf = self.map.keyframes.get(kf_id)
        if kf is None:
            return None
        kfs = sorted((k for k in segment_keyframes(self.map, kf.segment) if k.id >= self.first_session_kf),
                     key=lambda k: k.timestamp)
        var = set(problem.kf_ids.tolist()) - set(problem.fixed_kf_ids.tolist())
        i = len(kfs)
        while i > 0 and kfs[i - 1].id in var:
            i -= 1
        if i == len(kfs):
            return None
        return build_chain(kfs[max(i - 1, 0):], self.inertial.imu, self.inertial.calib, self._imu_params(),
                           cache=self._pims)

    def _solve(self, job):
        return solve_inertial_job(self.config.local, job)

    def _finish(self, job, result):
        out = super()._finish(job, result)
        if out is not None and isinstance(result, InertialBAResult):
            self.counts["vi_ba_calls"] += 1
            with self.lock:
                self._store(result)
        return out

    def _store(self, result: InertialBAResult) -> None:
        ids = []
        for kid, v in result.velocities.items():
            kf = self.map.keyframes.get(kid)
            if kf is not None and np.all(np.isfinite(v)) and np.all(np.isfinite(result.biases[kid])):
                store_state(kf, v, result.biases[kid])
                ids.append(kid)
        if self.estimated is not None:
            self.estimated.update(ids)
        for cb in self.state_listeners:
            cb(ids)

    # ------------------------------------------------------------------ full VI-BA
    def full_inertial_ba(self, segment: int, monocular: bool) -> InertialBAResult | None:
        """VI-BA over every good keyframe of ``segment`` and their points: the first keyframe's pose
        fixed (position and yaw are the gauge; the world is gravity-aligned), its velocity and biases
        free under :data:`FULL_BA_PRIOR`; every other keyframe's state free. Snapshot under the
        lock, solved without it, written back under it (as :meth:`global_ba`); stale when the map
        moved meanwhile."""
        if not self.active or not (self._vi_local or self.sensor == "rgbd"):
            return None
        if self._parallel:
            self._queue.settle()
        t0 = time.perf_counter()
        with self.lock:
            kfs = sorted(segment_keyframes(self.map, segment), key=lambda k: k.timestamp)
            if len(kfs) < 3:
                return None
            pts = self.map.local_point_ids([k.id for k in kfs])
            built = self._problem([k.id for k in kfs[1:]], [kfs[0].id], pts, -1)
            chain = build_chain(kfs, self.inertial.imu, self.inertial.calib, self._imu_params(), free_first=True,
                                bias_prior=FULL_BA_PRIOR["mono" if monocular else "stereo"])
            if built is None or chain is None:
                return None
            problem, ctx = built
            epoch = self.map.loop_epoch
            known = set(self.map.keyframes)
        try:
            result = inertial_bundle_adjustment(problem, chain, self.inertial.calib.T_imu_cam, self.config.global_ba)
        except Exception as exc:
            log.warning("full VI-BA failed: %s", exc)
            return None
        if not self._write_back_global(problem, result, ctx, epoch, known, "full VI-BA",
                                       then=lambda: self._store(result)):
            return None
        self.counts["vi_ba_full_calls"] += 1
        summary = {"keyframes": problem.num_keyframes, "points": problem.num_points,
                   "rms_px": [round(result.initial_rms_px, 4), round(result.final_rms_px, 4)],
                   "imu_cost": [round(c, 3) for c in result.imu_cost], "iterations": result.iterations,
                   "ms": round(1e3 * (time.perf_counter() - t0), 1)}
        self.full_ba_results.append(summary)
        log.info("full VI-BA: %s", summary)
        return result

    def stats(self) -> dict:
        out = super().stats()
        if self.full_ba_results:
            out["vi_ba_full"] = self.full_ba_results
        return out
