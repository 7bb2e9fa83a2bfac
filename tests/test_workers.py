"""fitter.workers: BLAS held to one thread in a process and in the processes it forks."""

import os
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from fitter.workers import one_blas_thread

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="forked processes")


def _blas_threads() -> list[int]:
    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


def _threads_around_a_nested_block() -> tuple[int, int, list[int]]:
    """This process's threads before and after a `one_blas_thread` block and a BLAS product in it."""
    before = len(os.listdir("/proc/self/task"))
    with one_blas_thread():
        a = np.random.default_rng(0).standard_normal((300, 300))
        a @ a
        inside = _blas_threads()
    return before, len(os.listdir("/proc/self/task")), inside


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="counts threads in /proc")
def test_a_process_forked_inside_the_block_keeps_one_blas_thread_and_starts_no_pool():
    with one_blas_thread():
        assert set(_blas_threads()) == {1}
        with ProcessPoolExecutor(1) as pool:
            before, after, inside = pool.submit(_threads_around_a_nested_block).result()
    assert set(inside) == {1}
    # a nested block sets nothing: setting OpenBLAS's thread count in a forked process starts its thread pool
    assert after == before


def test_the_outer_block_restores_the_thread_counts_and_nesting_keeps_the_limit():
    outside = _blas_threads()
    with one_blas_thread():
        with one_blas_thread():
            assert set(_blas_threads()) == {1}
        assert set(_blas_threads()) == {1}  # the inner block's end does not lift the outer one's limit
    assert _blas_threads() == outside
