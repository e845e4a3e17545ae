"""Jobs of one rule side by side in forked workers (enclab.core.parallel)."""
import os

import numpy as np
import pytest

from enclab.core import parallel


def _square_and_pid(x):
    return x * x, os.getpid()


def _fail_on_three(x):
    if x == 3:
        raise ValueError(f"job {x} failed")
    return x


def test_results_come_back_in_job_order_from_several_workers():
    jobs = [(np.float64(x),) for x in range(8)]
    serial = parallel.map_forked(_square_and_pid, jobs, 1)
    forked = parallel.map_forked(_square_and_pid, jobs, 2)
    assert [r for r, _ in forked] == [r for r, _ in serial] == [x * x for x in range(8)]
    assert {pid for _, pid in serial} == {os.getpid()}
    assert os.getpid() not in {pid for _, pid in forked}


def test_a_failing_job_raises_its_own_error_in_the_caller():
    with pytest.raises(ValueError, match="job 3 failed"):
        parallel.map_forked(_fail_on_three, [(x,) for x in range(6)], 2)


def test_one_job_or_one_process_runs_here():
    assert parallel.map_forked(_square_and_pid, [(2,)], 4) == [(4, os.getpid())]
    assert parallel.map_forked(_square_and_pid, [], 4) == []


def test_calls_of_different_functions_share_one_pool():
    calls = [(_square_and_pid, (3,)), (_fail_on_three, (5,)), (_square_and_pid, (4,))]
    out = parallel.call_forked(calls, 2)
    assert [out[0][0], out[1], out[2][0]] == [9, 5, 16]
    assert parallel.call_forked(calls, 1) == [(9, os.getpid()), 5, (16, os.getpid())]


def _blas_threads():
    from threadpoolctl import threadpool_info
    return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]


def test_forked_workers_run_blas_on_one_thread_each():
    # numpy's BLAS is loaded here (numpy is imported), so each worker reports it.
    before = _blas_threads()
    assert before, "numpy's BLAS library not found by threadpoolctl"
    forked = parallel.map_forked(_blas_threads, [()] * 4, 2)
    assert all(threads == [1] * len(before) for threads in forked)
    assert _blas_threads() == before  # the caller's own limit is left as it was


def test_limit_blas_threads_sets_this_process_limit():
    from threadpoolctl import threadpool_limits
    with threadpool_limits(limits=None):  # restores the original limits on exit
        parallel.limit_blas_threads(1)
        assert set(_blas_threads()) == {1}
        parallel.limit_blas_threads(0)  # fewer than one thread means one
        assert set(_blas_threads()) == {1}
