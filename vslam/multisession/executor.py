"""Where the tasks of ``vslam map`` run: a local process pool or Ray (the bench's executors'
pattern, :mod:`vslam.bench.harness`, for any picklable top-level function).

* ``local``: a pool of ``workers`` ``spawn`` processes (default ``os.cpu_count()``) kept for the
  executor's life, so that a task does not pay a fresh interpreter, vslam's imports and the
  compiled kernels' cache loads each time (1.5-4 s a task, more than a merge task's own work);
  when a worker dies (a crash, the OOM killer) the pool is broken: the tasks it had not finished
  are run again, each in a fresh process of its own, so that only the one that kills its process
  fails. ``workers=0`` runs the tasks one after the other in the calling process (debugging, tests).
* ``ray``: each task is a Ray task (``num_cpus=1``, no retries) on the cluster at ``address``, or
  on a local Ray started when the executor is entered (``num_cpus=workers or os.cpu_count()``, no
  dashboard, its session folder in a temporary directory removed at the end) and shut down when it
  is left. Tasks get paths and small records and write their results as files (run folders) on
  storage every node sees (``OUT``); what comes back through the object store is a small dict.

A task whose process dies (or whose Ray task fails) gives ``on_error(args, message)`` in its place.

``map`` runs a batch and waits for all of it; ``submit`` / ``wait_any`` run tasks one at a time as
their inputs become ready (the dataflow merge of :mod:`vslam.multisession.tree_merge`): ``submit``
returns a :class:`Pending` at once (``workers=0``: the task has already run, inline), ``wait_any``
blocks until one of the given tasks is done and returns it with its result. A local task whose pool
breaks runs again alone in a fresh process (as in ``map``); ``slots`` is how many tasks run at once.
"""
from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

from vslam.errors import VslamError


def _in_fresh_process(fn: Callable, args: tuple) -> Any:
    ctx = multiprocessing.get_context("spawn")
    with cf.ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        return pool.submit(fn, *args).result()


@dataclass(eq=False)
class Pending:
    """A submitted task (:meth:`TaskExecutor.submit`): its future (a ``concurrent.futures`` one or a
    Ray ``ObjectRef``), and once ``done`` its result (``on_error``'s record if it failed)."""

    fn: Callable
    args: tuple
    on_error: Callable[[tuple, str], Any]
    future: Any = None
    pool: Any = None
    alone: bool = False
    done: bool = False
    result: Any = None


class TaskExecutor:
    """``with TaskExecutor("ray", workers=2) as ex: ex.map(fn, [args, ...], on_error)``."""

    def __init__(self, kind: str = "local", workers: int | None = None, address: str | None = None) -> None:
        if kind not in ("local", "ray"):
            raise VslamError(f"unknown executor {kind!r}; use local or ray")
        if address and kind != "ray":
            raise VslamError("--address is for --executor ray")
        if workers is not None and workers < 0:
            raise VslamError(f"--workers must be >= 0, got {workers}")
        if kind == "ray":
            try:
                import ray  # noqa: F401
            except ImportError:
                raise VslamError("--executor ray needs Ray: pip install 'vslam[ray]' (ray==2.60.0)") from None
        self.kind, self.address = kind, address
        self.workers = (os.cpu_count() or 1) if workers is None else workers
        self._started = False
        self._tmp: Path | None = None
        self._pool: cf.ProcessPoolExecutor | None = None
        self._threads: cf.ThreadPoolExecutor | None = None
        self._remotes: dict[Callable, Any] = {}

    @property
    def description(self) -> str:
        if self.kind == "ray":
            return f"ray ({self.address})" if self.address else f"ray (local, {max(self.workers, 1)} CPUs)"
        return "local (in process)" if self.workers == 0 else f"local ({self.workers} processes)"

    def _new_pool(self) -> cf.ProcessPoolExecutor:
        return cf.ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"))

    def __enter__(self) -> "TaskExecutor":
        if self.kind != "ray":
            return self
        import ray

        if ray.is_initialized():
            return self
        if self.address:
            ray.init(address=self.address, log_to_driver=False)
        else:
            from vslam.bench.harness import start_local_ray

            self._tmp = start_local_ray(max(self.workers, 1))
        self._started = True
        return self

    def __exit__(self, *exc) -> None:
        if self._threads is not None:
            self._threads.shutdown(wait=True, cancel_futures=True)
            self._threads = None
        self._remotes.clear()
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        if self._started:
            from vslam.bench.harness import stop_ray

            stop_ray(local=not self.address)
            self._started = False
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def map(self, fn: Callable, args_list: Sequence[tuple], on_error: Callable[[tuple, str], Any]) -> list:
        """``[fn(*args) for args in args_list]``, run as tasks (:meth:`submit`, all at once, one CPU
        each); results in the order of ``args_list``. A worker that dies breaks the local pool: the
        tasks it had not finished run again, each alone in a fresh process, so only the one that
        kills its process fails."""
        tasks = [self.submit(fn, args, on_error) for args in args_list]
        out = []
        for task in tasks:
            while not task.done:
                self.wait_any([task])
            out.append(task.result)
        return out

    @property
    def slots(self) -> int:
        """How many tasks run at once: the local workers (1 in process), or the Ray cluster's CPUs."""
        if self.kind == "ray":
            import ray

            if ray.is_initialized():
                return max(int(ray.cluster_resources().get("CPU", 1)), 1)
        return max(self.workers, 1)

    def submit(self, fn: Callable, args: tuple, on_error: Callable[[tuple, str], Any], cpus: int = 1) -> Pending:
        """Start ``fn(*args)`` as a task and return at once (``workers=0``: run it now, inline).
        ``cpus``: the CPUs a Ray task asks for (a merge that verifies in a second thread while no
        other task runs asks for 2, :mod:`vslam.multisession.tree_merge`); a local task runs in one
        of the pool's processes whatever it asks."""
        task = Pending(fn, tuple(args), on_error)
        if self.kind == "ray":
            if fn not in self._remotes:
                import ray

                self._remotes[fn] = ray.remote(num_cpus=1, max_retries=0)(fn)
            remote = self._remotes[fn] if cpus == 1 else self._remotes[fn].options(num_cpus=cpus)
            try:
                task.future = remote.remote(*task.args)
            except Exception as exc:  # noqa: BLE001 - the task could not be sent
                task.done, task.result = True, on_error(task.args, f"Ray task failed: {type(exc).__name__}: {exc}")
        elif self.workers == 0:
            task.done, task.result = True, fn(*task.args)
        else:
            if self._pool is None:
                self._pool = self._new_pool()
            task.pool = self._pool
            try:
                task.future = self._pool.submit(fn, *task.args)
            except (cf.process.BrokenProcessPool, RuntimeError):  # broken by a task that died meanwhile
                self._alone(task)
        return task

    def _alone(self, task: Pending) -> None:
        """Run ``task`` again in a fresh process of its own (its pool broke: a worker died)."""
        if task.pool is not None and task.pool is self._pool:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
        if self._threads is None:
            self._threads = cf.ThreadPoolExecutor(max_workers=max(self.workers, 1))
        task.alone = True
        task.future = self._threads.submit(_in_fresh_process, task.fn, task.args)

    def _settle(self, task: Pending) -> None:
        """A local task whose future is done: its result, or a rerun alone if its pool broke."""
        try:
            task.result = task.future.result()
        except cf.process.BrokenProcessPool:
            if not task.alone:
                self._alone(task)
                return
            task.result = task.on_error(task.args, "the task's process failed: BrokenProcessPool")
        except Exception as exc:  # noqa: BLE001 - the task could not be sent or its result not returned
            what = "the task's process failed" if task.alone else "the task failed"
            task.result = task.on_error(task.args, f"{what}: {type(exc).__name__}: {exc}")
        task.done = True

    def wait_any(self, tasks: Sequence[Pending]) -> tuple[Pending, Any]:
        """Block until one of ``tasks`` is done; that task (the first done in ``tasks``'s order) and
        its result. Raises ValueError when ``tasks`` is empty."""
        if not tasks:
            raise ValueError("wait_any: no tasks")
        while True:
            for task in tasks:
                if task.done:
                    return task, task.result
            if self.kind == "ray":
                import ray

                by_ref = {task.future: task for task in tasks}
                ready, _ = ray.wait(list(by_ref), num_returns=1)
                task = by_ref[ready[0]]
                try:
                    task.result = ray.get(ready[0])
                except Exception as exc:  # noqa: BLE001 - worker died, task could not be pickled, ...
                    task.result = task.on_error(task.args, f"Ray task failed: {type(exc).__name__}: {exc}")
                task.done = True
                continue
            done, _ = cf.wait([task.future for task in tasks], return_when=cf.FIRST_COMPLETED)
            for task in tasks:
                if task.future in done:
                    self._settle(task)
