"""Independent fits on several processes: the diagnosis' candidates of a round and its held-out refits, an
effect fit's screened starts and raced refinements.

Each candidate effect of a diagnosis round is fitted on the same base, independently of
the others (`fitter.diagnosis.rounds.candidate_round`), each recording's
held-out refit is independent of the others' (`fitter.diagnosis.held_out`), and so are the screened starts
and the raced refinements of ``duhem fit --effects`` (`fitter.identification.effects_fit`):
`parallel_map` runs them on up to `workers()` processes.  The processes are
forked, so they inherit the experiment and the fits made so far; only the
item (an effect name, a recording index, a start) goes to a process and only its
result (a `Fit`, a `RefineResult`) comes back.  Every fit is deterministic, so the result
is the same on any number of processes (tested).  A map inside a worker, or in a daemonic process (a Dask
worker of ``duhem batch``, which may not have children), runs in that process.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from typing import Callable, Sequence, TypeVar

__all__ = ["WORKERS_ENV", "parallel_map", "workers"]

WORKERS_ENV = "DUHEM_WORKERS"
"""Environment variable: the number of processes of the independent fits (default: the machine's cores)."""

T = TypeVar("T")
R = TypeVar("R")
_TASK: Callable | None = None
_IN_WORKER = False


def workers() -> int:
    """Processes for the independent fits: ``DUHEM_WORKERS`` when set (a whole number >= 1), else the cores."""
    value = os.environ.get(WORKERS_ENV, "").strip()
    if value:
        try:
            return max(1, int(value))
        except ValueError:
            raise ValueError(f"{WORKERS_ENV}={value!r}: give a whole number of processes >= 1") from None
    return os.cpu_count() or 1


def _call(item):
    global _IN_WORKER
    _IN_WORKER = True  # a map inside a worker runs in that worker (no processes of processes)
    return _TASK(item)


def parallel_map(function: Callable[[T], R], items: Sequence[T]) -> list[R]:
    """[function(item) for item in items], on up to `workers()` forked processes (in order)."""
    n = min(workers(), len(items))
    if (
        n <= 1
        or _IN_WORKER
        or multiprocessing.current_process().daemon
        or "fork" not in multiprocessing.get_all_start_methods()
    ):
        return [function(item) for item in items]
    global _TASK
    _TASK = function
    try:
        with ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("fork")) as pool:
            return list(pool.map(_call, items))
    finally:
        _TASK = None
