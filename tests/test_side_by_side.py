"""fitter.workers.side_by_side: two computations at once, one forked, the answers and errors of the turn, and the
core of the lane that ends taken by the other's next map."""

import multiprocessing
import os

import numpy as np
import pytest

from fitter import workers
from fitter.workers import evaluation_map, parallel_map, side_by_side

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="forked processes")


def test_the_first_runs_in_a_forked_process_the_second_here_and_both_answers_come_back(monkeypatch):
    here = os.getpid()
    monkeypatch.setenv("DUHEM_WORKERS", "2")
    first, second = side_by_side(lambda: (os.getpid(), np.arange(3.0)), lambda: os.getpid())
    assert first[0] != here and second == here and first[1].tolist() == [0.0, 1.0, 2.0]
    assert workers._SPARE is None  # nothing of the lanes is left
    monkeypatch.setenv("DUHEM_WORKERS", "1")
    assert side_by_side(os.getpid, os.getpid) == (here, here)  # in turn on one process


def test_the_first_ones_error_is_raised_before_the_seconds_as_in_turn(monkeypatch):
    monkeypatch.setenv("DUHEM_WORKERS", "2")

    def fails(error):
        def run():
            raise error

        return run

    with pytest.raises(ValueError, match="first"):
        side_by_side(fails(ValueError("first")), fails(KeyError("second")))
    with pytest.raises(KeyError, match="second"):
        side_by_side(lambda: 1, fails(KeyError("second")))
    with pytest.raises(ValueError, match="first"):
        side_by_side(fails(ValueError("first")), lambda: 2)
    assert side_by_side(lambda: 1, lambda: 2) == (1, 2)


def test_a_map_in_a_lane_takes_the_core_the_other_lane_gives_back(monkeypatch):
    """While the forked lane runs, the map here runs its items here, one by one; the forked lane ends when the
    first item lets it, and gives its core back; the items left then run on forked processes."""
    monkeypatch.setenv("DUHEM_WORKERS", "2")
    here, go = os.getpid(), multiprocessing.get_context("fork").Event()

    def item(k: int) -> int:
        if k == 0:
            assert workers._take_cores(1) == 0  # the forked lane holds the other core
            go.set()
            while workers._SPARE.value == 0:  # until the forked lane has given its core back
                go.wait(0.01)
        return os.getpid()

    forked, pids = side_by_side(lambda: go.wait(10), lambda: parallel_map(item, range(4)))
    assert forked is True
    assert pids[0] == here and here not in pids[1:]


def test_an_evaluation_map_in_a_lane_forks_once_a_core_is_spare_and_gives_it_back(monkeypatch):
    monkeypatch.setenv("DUHEM_WORKERS", "2")
    monkeypatch.setattr(workers, "POOL_AFTER_S", 0.0)
    go = multiprocessing.get_context("fork").Event()
    xs = [np.array([float(k)]) for k in range(4)]

    def second() -> tuple[int, int, list, int]:
        with evaluation_map(np.negative) as mapper:
            mapper(np.negative, xs)
            alone = len(mapper._peers)  # no core spare: still this process alone
            go.set()
            while workers._SPARE.value == 0:
                go.wait(0.01)
            mapper(np.negative, xs)  # the first map to see the spare core forks after it
            pooled = mapper(np.negative, xs)
            peers = len(mapper._peers)
        return alone, peers, [float(o[0]) for o in pooled], workers._SPARE.value

    _, (alone, peers, pooled, spare_after) = side_by_side(lambda: go.wait(10), second)
    assert (alone, peers) == (0, 1) and pooled == [0.0, -1.0, -2.0, -3.0]
    assert spare_after == 1  # the evaluation process's core given back when the map ended
