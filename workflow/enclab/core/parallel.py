"""Independent CPU-bound jobs of one rule on the cores the rule was given."""
from __future__ import annotations

import concurrent.futures
import multiprocessing as mp
from typing import Any, Callable, Sequence

from threadpoolctl import threadpool_limits

__all__ = ["call_forked", "limit_blas_threads", "map_forked"]


def limit_blas_threads(threads: int) -> None:
    """Let BLAS (OpenBLAS, MKL, BLIS) run at most ``threads`` threads in this process.

    OpenBLAS starts one thread per core of the machine, whatever the cores a job was given;
    a job's own processes (:func:`map_forked`) are its parallelism, and BLAS threads on top
    of them put more threads than cores on the machine. The LRDE stage of the embedded
    closed-loop log on two forked workers takes about 28 % less wall time with one BLAS
    thread per worker, and its output is byte-identical (``docs/benchmarks/lrde_stage.csv``).
    """
    threadpool_limits(limits=max(1, int(threads)), user_api="blas")


def map_forked(fn: Callable[..., Any], jobs: Sequence[tuple], processes: int) -> list:
    """``[fn(*job) for job in jobs]``, with up to ``processes`` jobs at a time.

    The jobs go to ``processes`` forked workers in order, each taking the next job when it
    is done (the caller waits, so it holds no core of its own); forked workers start at once
    and see the caller's modules without importing them again. With one process, one job or
    no ``fork`` (Windows), the jobs run here in order. The results are the same in every case
    when ``fn`` is deterministic; an exception of a job is raised here after the jobs not yet
    started are cancelled. Each worker runs BLAS on one thread (:func:`limit_blas_threads`).
    Only work that uses numpy, scipy and the standard library belongs here: a forked worker
    must not touch a thread pool of the parent (Arrow's, for one).
    """
    jobs = list(jobs)
    if len(jobs) < 2 or processes < 2 or "fork" not in mp.get_all_start_methods():
        return [fn(*job) for job in jobs]
    with concurrent.futures.ProcessPoolExecutor(
            max_workers=min(processes, len(jobs)), mp_context=mp.get_context("fork"),
            initializer=limit_blas_threads, initargs=(1,)) as pool:
        pending = [pool.submit(fn, *job) for job in jobs]
        try:
            return [future.result() for future in pending]
        except BaseException:
            for future in pending:
                future.cancel()
            raise


def call_forked(calls: Sequence[tuple[Callable[..., Any], tuple]], processes: int) -> list:
    """``[fn(*args) for fn, args in calls]`` as :func:`map_forked` runs them: jobs of
    different kinds share one pool, so that a short one does not leave a core idle."""
    return map_forked(_call, [(fn, tuple(args)) for fn, args in calls], processes)


def _call(fn, args):
    return fn(*args)
