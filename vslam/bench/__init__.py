"""vslam.bench: run a benchmark spec (many sequences, repeated) locally or on Ray and summarize it.

>>> from vslam.bench import load_spec, run_benchmark, LocalExecutor
>>> spec = load_spec("benchmarks/smoke.yaml")                      # doctest: +SKIP
>>> result = run_benchmark(spec, "bench_out", LocalExecutor(1))    # doctest: +SKIP
>>> result.files["md"].read_text()                                 # doctest: +SKIP
"""
from vslam.bench.harness import (
    BenchResult, Job, LocalExecutor, RayExecutor, execute_job, make_executor, make_jobs, run_benchmark,
)
from vslam.bench.results import read_results, summarize, write_results
from vslam.bench.spec import BenchSpec, RunSpec, load_spec, parse_spec

__all__ = [
    "BenchResult", "BenchSpec", "Job", "LocalExecutor", "RayExecutor", "RunSpec", "execute_job", "load_spec",
    "make_executor", "make_jobs", "parse_spec", "read_results", "run_benchmark", "summarize", "write_results",
]
