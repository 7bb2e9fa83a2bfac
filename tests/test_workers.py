"""fitter.workers: BLAS held to one thread in a process and in the processes it forks."""

import os
import threading
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from fitter.workers import one_blas_thread, one_blas_thread_to_exit

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


def test_a_block_in_another_thread_after_one_in_this_thread_still_sets_the_limit():
    """threadpoolctl lets one thread at a time set OpenBLAS's count; a block hands that back at its end."""
    with one_blas_thread():
        pass
    seen = []

    def other() -> None:
        with one_blas_thread():
            seen.append(_blas_threads())

    thread = threading.Thread(target=other)
    thread.start()
    thread.join(10)
    assert [set(s) for s in seen] == [{1}]


def _a_process_that_keeps_the_limit() -> tuple[list[int], int, int, list[int], int]:
    """In a forked process: `one_blas_thread_to_exit`, then a block with a fork inside and a second block; the
    BLAS thread counts before, this process's threads inside the first block after its fork and after each block,
    and the BLAS thread counts at the end."""
    before = _blas_threads()
    one_blas_thread_to_exit()
    with one_blas_thread():
        child = os.fork()
        if child == 0:
            os._exit(0)
        os.waitpid(child, 0)
        inside = len(os.listdir("/proc/self/task"))
    after_first = len(os.listdir("/proc/self/task"))
    with one_blas_thread():
        pass
    return before, inside, after_first, _blas_threads(), len(os.listdir("/proc/self/task"))


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="counts threads in /proc")
@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="BLAS on one core has one thread anyway")
def test_a_process_held_to_its_exit_keeps_one_blas_thread_after_its_blocks_and_starts_no_threads():
    with ProcessPoolExecutor(1) as pool:
        before, inside, after_first, blas_at_end, after_second = pool.submit(_a_process_that_keeps_the_limit).result()
    assert set(before) == set(_blas_threads()) and max(before) > 1  # the limit is set at the first block
    assert set(blas_at_end) == {1}  # neither block's end restored the count
    # a restore after the fork would start OpenBLAS's threads again; kept, the process has the threads it had
    assert after_first == inside and after_second == inside
