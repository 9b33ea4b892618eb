"""Execute a benchmark spec: every (run, repeat) as one job, on a local process pool or on Ray.

Each job runs SLAM once (``vslam.api.run_path`` unless a ``runner`` is injected) into
``DIR/runs/<name>/<repeat>/`` (the ``vslam run`` folder, plus ``log.txt``) and yields one *row*
of ``results.json``. A job that fails (an exception, or its process dying) gives a row with
``"status": "failed"`` and ``"error"``; the other jobs go on.

Executors:

* :class:`LocalExecutor` (default): each job in its own fresh process (``spawn``), ``workers`` of
  them at a time (default 1, so runs do not compete for the CPU and ``fps`` stays comparable;
  ``workers=None`` uses ``os.cpu_count()``). ``workers=0`` runs the jobs one after the other in
  the calling process (debugging, tests that monkeypatch).
* :class:`RayExecutor`: each job is a Ray task (``num_cpus=1``) on the cluster at ``address``, or
  on a local Ray started on demand (``ray.init(num_cpus=workers or os.cpu_count())``, no
  dashboard, its session folder in a temporary directory removed afterwards). Tasks write their
  run folder on the worker and send the files back, so workers need no shared output folder; they
  do need vslam installed and the sequences at the same paths.

A *runner* is any picklable callable with the signature of :func:`vslam.api.run_path`
(``runner(path, output, sensor=, dataset=, config=, overrides=, max_frames=, start_frame=,
progress=)``) returning a :class:`vslam.runner.RunResult` or a stats dict.
"""
from __future__ import annotations

import concurrent.futures as cf
import logging
import multiprocessing
import os
import shutil
import tempfile
import time
import traceback
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Sequence

from vslam.bench.spec import BenchSpec, RunSpec
from vslam.errors import VslamError

log = logging.getLogger(__name__)

Runner = Callable[..., Any]
OnResult = Callable[[dict, int, int], None]

#: the columns every row of ``results.json`` has (the issue's contract), then extras
ROW_KEYS = ("name", "repeat", "sensor", "frames", "tracked", "ate_rmse", "rpe_trans_rmse", "fps",
            "realtime_factor", "wall_s")


@dataclass(frozen=True)
class Job:
    """One execution: ``run`` for the ``repeat``-th time (0-based) into ``output_dir``."""

    run: RunSpec
    repeat: int
    output_dir: Path
    system: str = "vslam"  # or the baseline's name

    @property
    def label(self) -> str:
        return f"{self.run.name}#{self.repeat}"

    @property
    def rel_output(self) -> str:
        """The run folder relative to the benchmark folder."""
        return f"runs/{self.run.name}/{self.repeat}"


def make_jobs(spec: BenchSpec, output: str | Path) -> list[Job]:
    """All (run, repeat) jobs of ``spec``, repeat-major (every run once, then every run again), so
    repeats of one run are spread in time rather than back to back."""
    output = Path(output)
    n_max = max((r.repeats for r in spec.runs), default=0)
    return [Job(run, k, output / "runs" / run.name / str(k))
            for k in range(n_max) for run in spec.runs if k < run.repeats]


# ----------------------------------------------------------------------------------------------
# one job
# ----------------------------------------------------------------------------------------------
def sensor_frame_rate(run: RunSpec, sensor: str | None) -> float | None:
    """Frames per second the sensor delivered over the frames the run used.

    From the dataset's timestamps (``(n - 1) / (t_last - t_first)`` over the run's frame range, so a
    keyframe subset such as ``tum_fr3_cabinet_keyframes58`` counts at its real 1.5 Hz), else the
    dataset's nominal ``frame_rate``; None when the dataset cannot be opened.
    """
    try:
        from vslam.datasets import open_dataset
        from vslam.inertial.sensors import split_sensor

        visual = split_sensor(sensor)[0] if sensor else None  # the images' rate, inertial or not
        ds = open_dataset(run.data, kind=run.dataset, sensor=visual)
    except Exception as exc:  # a broken dataset is reported by the run itself
        log.debug("frame rate of %s unknown: %s", run.data, exc)
        return None
    ts = ds.timestamps
    stop = len(ts) if run.max_frames is None else min(len(ts), run.start_frame + run.max_frames)
    ts = ts[run.start_frame:stop]
    if len(ts) >= 2 and ts[-1] > ts[0]:
        return float((len(ts) - 1) / (ts[-1] - ts[0]))
    rate = getattr(ds, "frame_rate", None)
    return float(rate) if rate else None


def make_row(job: Job, stats: dict, error: str | None = None, frame_rate: float | None = None,
             elapsed_s: float | None = None) -> dict:
    """One ``results.json`` row from a run's ``stats.json`` content."""
    fps = stats.get("fps")
    frame_rate = stats.get("frame_rate", frame_rate)
    rtf = round(float(fps) / float(frame_rate), 3) if fps is not None and frame_rate else None
    loops = stats.get("loops")
    row = {
        "name": job.run.name,
        "repeat": job.repeat,
        "sensor": stats.get("sensor", job.run.sensor),
        "frames": stats.get("frames"),
        "tracked": stats.get("tracked"),
        "ate_rmse": stats.get("ate_rmse"),
        "rpe_trans_rmse": stats.get("rpe_trans_rmse"),
        "fps": fps,
        "realtime_factor": rtf,
        "wall_s": stats.get("wall_s", round(elapsed_s, 3) if elapsed_s is not None else None),
        "rpe_rot_deg_rmse": stats.get("rpe_rot_deg_rmse"),
        "lost": stats.get("lost"),
        "keyframes": stats.get("keyframes"),
        "map_points": stats.get("map_points"),
        "loops": len(loops) if isinstance(loops, list) else loops,
        "frame_rate": round(frame_rate, 4) if frame_rate else None,
        "system": job.system,
        "paced": stats.get("paced"),  # a baseline fed at the sensor rate (fps capped by it)
        "data": str(job.run.data),
        "output": job.rel_output,
        "status": "failed" if error else "ok",
        "error": error,
    }
    return row


def _load_stats(folder: Path) -> dict:
    import json

    try:
        return json.loads((folder / "stats.json").read_text())
    except (OSError, ValueError):
        return {}


def execute_job(job: Job, runner: Runner | None = None, log_file: bool = True, own_process: bool = False) -> dict:
    """Run one job and return its row; never raises for a failing run (the error is in the row).

    ``runner`` defaults to :func:`vslam.api.run_path` (looked up at call time). With ``log_file``
    the run's log records go to ``<output_dir>/log.txt``: INFO and up when ``own_process`` (a
    worker process whose root logger we may lower), else what the caller's logging lets through.
    """
    out = job.output_dir
    out.mkdir(parents=True, exist_ok=True)
    handler = None
    if log_file:
        handler = logging.FileHandler(out / "log.txt", mode="w")
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        handler.setLevel(logging.INFO)
        root = logging.getLogger()
        root.addHandler(handler)
        if own_process and (root.level > logging.INFO or root.level == logging.NOTSET):
            root.setLevel(logging.INFO)
    if runner is None:
        from vslam import api

        runner = api.run_path
    run = job.run
    t0 = time.perf_counter()
    error = None
    stats: dict = {}
    try:
        log.info("%s: %s (%s) -> %s", job.label, run.data, run.sensor or "auto", out)
        result = runner(str(run.data), out, sensor=run.sensor, dataset=run.dataset,
                        config=str(run.config) if run.config else None, overrides=list(run.overrides),
                        max_frames=run.max_frames, start_frame=run.start_frame, progress=False)
        stats = dict(result if isinstance(result, dict) else getattr(result, "stats", {}) or {})
        if not stats:
            stats = _load_stats(out)
        if stats.get("error"):
            error = str(stats["error"])
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # noqa: BLE001 - a failing run must not stop the benchmark
        error = f"{type(exc).__name__}: {exc}"
        # a fault of the input or the machine (VslamError: bad data, a full disk) is its one line; a bug
        # keeps its traceback
        tb = "" if isinstance(exc, VslamError) else "\n" + traceback.format_exc()
        log.error("%s failed: %s%s", job.label, error, tb)
        stats = _load_stats(out)  # a crashed run keeps its partial stats (runner writes them)
    elapsed = time.perf_counter() - t0
    rate = stats.get("frame_rate") or sensor_frame_rate(run, stats.get("sensor", run.sensor))
    row = make_row(job, stats, error, rate, elapsed)
    if handler is not None:
        logging.getLogger().removeHandler(handler)
        handler.close()
    return row


def failure_row(job: Job, error: str) -> dict:
    """The row of a job whose process died or could not be started."""
    return make_row(job, _load_stats(job.output_dir), error)


# ----------------------------------------------------------------------------------------------
# executors
# ----------------------------------------------------------------------------------------------
def _run_in_fresh_process(job: Job, runner: Runner | None) -> dict:
    """``execute_job`` in a new ``spawn`` process (a crash or leak cannot affect other jobs)."""
    ctx = multiprocessing.get_context("spawn")
    try:
        with cf.ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
            return pool.submit(execute_job, job, runner, True, True).result()
    except cf.process.BrokenProcessPool as exc:
        return failure_row(job, f"the run's process died ({exc}); see {job.output_dir / 'log.txt'}")
    except Exception as exc:  # e.g. an unpicklable runner
        return failure_row(job, f"{type(exc).__name__}: could not run in a subprocess: {exc}")


class LocalExecutor:
    """Run jobs on this machine: ``workers`` fresh processes at a time (see the module docstring).

    Args:
        workers: concurrent processes; 1 (default) for comparable timings, None for
            ``os.cpu_count()``, 0 to run in the calling process.
    """

    name = "local"

    def __init__(self, workers: int | None = 1) -> None:
        if workers is not None and workers < 0:
            raise VslamError(f"--workers must be >= 0, got {workers}")
        self.workers = (os.cpu_count() or 1) if workers is None else workers

    def map(self, jobs: Sequence[Job], runner: Runner | None = None, on_result: OnResult | None = None) -> list[dict]:
        rows: list[dict | None] = [None] * len(jobs)
        if self.workers == 0:
            for i, job in enumerate(jobs):
                rows[i] = execute_job(job, runner)
                if on_result:
                    on_result(rows[i], i + 1, len(jobs))
            return rows  # type: ignore[return-value]
        with cf.ThreadPoolExecutor(max_workers=self.workers) as threads:
            futures = {threads.submit(_run_in_fresh_process, job, runner): i for i, job in enumerate(jobs)}
            for done, fut in enumerate(cf.as_completed(futures), 1):
                i = futures[fut]
                rows[i] = fut.result()
                if on_result:
                    on_result(rows[i], done, len(jobs))
        return rows  # type: ignore[return-value]


def _ray_job(job: Job, runner: Runner | None) -> tuple[dict, dict[str, bytes]]:
    """Ray task body: run into a worker-local folder and return the row and the folder's files."""
    tmp = Path(tempfile.mkdtemp(prefix="vslam-bench-"))
    try:
        local = replace(job, output_dir=tmp / "run")
        row = execute_job(local, runner, own_process=True)
        files = {str(p.relative_to(local.output_dir)): p.read_bytes()
                 for p in sorted(local.output_dir.rglob("*")) if p.is_file()}
        return row, files
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


class RayExecutor:
    """Run every job as a Ray task (see the module docstring).

    Args:
        address: a running cluster (``ray://host:10001``, ``host:6379`` or ``auto``); None starts a
            local Ray for the duration of :meth:`map`.
        workers: CPUs of the local Ray (default ``os.cpu_count()``); ignored with ``address``.
        temp_dir: the local Ray's session folder (default: a fresh temporary folder, removed after).
    """

    name = "ray"

    def __init__(self, address: str | None = None, workers: int | None = None,
                 temp_dir: str | Path | None = None) -> None:
        try:
            import ray  # noqa: F401
        except ImportError:
            raise VslamError("--executor ray needs Ray: pip install 'vslam[ray]' (ray==2.60.0)") from None
        self.address = address
        self.workers = workers
        self.temp_dir = Path(temp_dir) if temp_dir else None

    def _init(self) -> tuple[bool, Path | None]:
        import ray

        if ray.is_initialized():
            return False, None
        if self.address:
            ray.init(address=self.address, log_to_driver=False)
            return True, None
        tmp = start_local_ray(self.workers or os.cpu_count() or 1, self.temp_dir)
        return True, (None if self.temp_dir else tmp)

    def map(self, jobs: Sequence[Job], runner: Runner | None = None, on_result: OnResult | None = None) -> list[dict]:
        import ray

        started, tmp = self._init()
        try:
            task = ray.remote(num_cpus=1, max_retries=0)(_ray_job)
            refs = {task.remote(job, runner): i for i, job in enumerate(jobs)}
            rows: list[dict | None] = [None] * len(jobs)
            pending = list(refs)
            done = 0
            while pending:
                ready, pending = ray.wait(pending, num_returns=1)
                for ref in ready:
                    i = refs[ref]
                    job = jobs[i]
                    try:
                        row, files = ray.get(ref)
                        job.output_dir.mkdir(parents=True, exist_ok=True)
                        for rel, data in files.items():
                            dst = job.output_dir / rel
                            dst.parent.mkdir(parents=True, exist_ok=True)
                            dst.write_bytes(data)
                    except Exception as exc:  # worker crashed, task could not be pickled, ...
                        row = failure_row(job, f"Ray task failed: {type(exc).__name__}: {exc}")
                    rows[i] = row
                    done += 1
                    if on_result:
                        on_result(row, done, len(jobs))
            return rows  # type: ignore[return-value]
        finally:
            if started:
                stop_ray(local=not self.address)
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)


def stop_ray(local: bool) -> None:
    """``ray.shutdown()``; ``local``: the Ray was started by this process (:func:`start_local_ray`),
    whose autoscaler monitor is killed first.

    ``ray.shutdown()`` stops each process of a Ray it started with SIGTERM and waits up to 1 s for it
    to exit (``ray._private.node.Node._kill_process_impl``). The autoscaler monitor does not exit
    within that second and is then killed anyway: 1.01 s of a 1.33 s shutdown (ray 2.60.0; 0.32 s
    with the monitor killed first). A one-machine Ray has nothing to scale, so it is killed at once.
    That goes through Ray's internals; where they differ, this is ``ray.shutdown()`` alone. A Ray
    reached by ``--address`` is only disconnected from, as before."""
    import ray

    if local:
        try:
            node = getattr(ray._private.worker, "_global_node", None)
            for info in (node.all_processes.get("monitor", []) if node is not None else []):
                info.process.kill()
        except Exception as exc:  # noqa: BLE001 - another Ray version: the plain shutdown below
            log.debug("could not stop Ray's monitor first: %s", exc)
    ray.shutdown()


def start_local_ray(num_cpus: int, temp_dir: Path | None = None, tries: int = 2) -> Path:
    """Start a local Ray instance (no dashboard, quiet); returns its session folder. Ray's socket
    paths must stay short (< 108 bytes), so the folder is a fresh one in /tmp unless given. On a
    loaded machine Ray's first start can time out waiting for its own GCS server; it is tried
    ``tries`` times, then refused with one line. ``num_workers_soft_limit`` stays at ``num_cpus``:
    by default a task that asks for every CPU makes Ray kill the idle workers and spawn new ones for
    the next tasks (a cold worker: its start-up and imports beside the running task; issue #26's
    fleet finalize 1.0 -> 1.3-1.8 s).

    The raylet connects to its own object store through a client that, when the store is not
    listening yet, waits ``raylet_client_connect_timeout_milliseconds`` (1000) before it tries again:
    a second lost in about one start of three (``ray.init`` 2.0-2.2 s or 3.0-3.2 s; ray 2.60.0,
    benchmarks/RESULTS.md round 13). It tries every 100 ms here, as often as 10 s allow (as the
    default's 10 x 1 s): 16 starts of 16 took 2.0-2.2 s."""
    import ray

    tmp = temp_dir or Path(tempfile.mkdtemp(prefix="vslam-ray-"))
    config = {"num_workers_soft_limit": num_cpus, "raylet_client_connect_timeout_milliseconds": 100,
              "raylet_client_num_connect_attempts": 100}
    for attempt in range(1, tries + 1):
        try:
            ray.init(num_cpus=num_cpus, include_dashboard=False, _temp_dir=str(tmp), log_to_driver=False,
                     configure_logging=False, _system_config=config)
            return tmp
        except RuntimeError as exc:  # e.g. "Timed out waiting for file .../gcs_server_port_..."
            ray.shutdown()
            log.warning("local Ray did not start (try %d of %d): %s", attempt, tries, exc)
            if attempt == tries:
                raise VslamError(f"could not start a local Ray instance ({exc}); is the machine overloaded? "
                                 "retry, or use --executor local") from None
    return tmp


def make_executor(kind: str = "local", workers: int | None = 1, address: str | None = None):
    """``local`` -> :class:`LocalExecutor`, ``ray`` -> :class:`RayExecutor`."""
    if kind == "local":
        if address:
            raise VslamError("--address is for --executor ray")
        return LocalExecutor(workers)
    if kind == "ray":
        return RayExecutor(address=address, workers=workers)
    raise VslamError(f"unknown executor {kind!r}; use local or ray")


# ----------------------------------------------------------------------------------------------
# the whole benchmark
# ----------------------------------------------------------------------------------------------
@dataclass
class BenchResult:
    """The rows of every job and where ``results.json`` / ``results.md`` / plots were written."""

    rows: list[dict]
    output_dir: Path
    files: dict[str, Path]

    @property
    def n_failed(self) -> int:
        return sum(1 for r in self.rows if r.get("status") != "ok")


def run_benchmark(
    spec: BenchSpec,
    output: str | Path,
    executor: Any = None,
    runner: Runner | None = None,
    on_result: OnResult | None = None,
    baselines: dict[str, Runner] | None = None,
    plots: bool = True,
) -> BenchResult:
    """Run every (run, repeat) of ``spec`` into ``output`` and write the results files.

    Args:
        executor: :class:`LocalExecutor` (default, one process at a time) or :class:`RayExecutor`.
        runner: the SLAM runner (default :func:`vslam.api.run_path`).
        on_result: ``on_result(row, n_done, n_total)`` after each job (progress output).
        baselines: ``{system_name: runner}`` run on the same jobs as well, their rows named
            ``<run>@<system>`` (e.g. ORB-SLAM3, see :mod:`vslam.bench.orbslam3_baseline`). With a
            one-at-a-time local executor each job's baselines run right after it (same machine
            load for both systems); otherwise all vslam jobs first, then each baseline's.
    """
    from vslam.bench.results import write_results

    output = Path(output)
    output.mkdir(parents=True, exist_ok=True)
    executor = executor or LocalExecutor()
    jobs = make_jobs(spec, output)
    groups: list[tuple[list[Job], Runner | None]] = [(jobs, runner)]
    for system, base_runner in (baselines or {}).items():
        bjobs = [Job(replace(j.run, name=f"{j.run.name}@{system}"), j.repeat,
                     output / "runs" / f"{j.run.name}@{system}" / str(j.repeat), system) for j in jobs]
        groups.append((bjobs, base_runner))
    if len(groups) > 1 and getattr(executor, "name", None) == "local" and getattr(executor, "workers", 1) <= 1:
        # one job at a time anyway: run each job's baselines right after it, so both systems are
        # timed under the same machine load (rows: run, run@baseline, next run, ...)
        groups = [([g[0][i]], g[1]) for i in range(len(jobs)) for g in groups]
    total = sum(len(g[0]) for g in groups)
    rows: list[dict] = []
    offset = 0
    t0 = time.perf_counter()
    for group_jobs, group_runner in groups:
        def progress(row: dict, done: int, _n: int, _offset: int = offset) -> None:
            if on_result:
                on_result(row, _offset + done, total)

        rows += executor.map(group_jobs, group_runner, progress)
        offset += len(group_jobs)
    if baselines:
        from vslam.bench.common_frames import add_common_frame_ate

        add_common_frame_ate(rows, output)
    meta = {
        "spec": str(spec.source) if spec.source else None,
        "description": spec.description,
        "executor": getattr(executor, "name", type(executor).__name__),
        "workers": getattr(executor, "workers", None),
        "total_wall_s": round(time.perf_counter() - t0, 3),
        "runs": [r.to_dict() for r in spec.runs],
    }
    files = write_results(rows, output, meta=meta, plots=plots)
    return BenchResult(rows=rows, output_dir=output, files=files)
