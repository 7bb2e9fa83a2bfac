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

`evaluation_map` does the same for the evaluations of one forward-difference Jacobian in
`fitter.identification.refine` (scipy's ``least_squares(workers=...)``): the evaluations of the columns are
independent, so on two cores a fit whose Jacobians cost most of its time takes about half the wall time, with the
same result to the last digit (each column is the same function of the same theta in whichever process).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from typing import Callable, Iterable, Iterator, Sequence, TypeVar

import numpy as np

__all__ = ["WORKERS_ENV", "evaluation_map", "parallel_map", "workers"]

WORKERS_ENV = "DUHEM_WORKERS"
"""Environment variable: the number of processes of the independent fits (default: the machine's cores)."""

T = TypeVar("T")
R = TypeVar("R")
POOL_AFTER_S = 0.02
"""`evaluation_map` forks its processes once one map of evaluations took this long in this process: below it a
fork (some milliseconds, measured 7-10 ms for a process of 300 MB) and the transfers cost about what they save."""

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


PARENT_POLL_S = 0.5
"""How often a forked worker looks whether its parent is still there (`_end_with`)."""


def _end_with(parent: int) -> None:
    """In a forked worker (`parallel_map`'s initialiser, `_serve`): a thread that ends it once its parent is gone
    (killed, say), which it sees as a new parent process id.  Without it a map's worker ran the items left in its
    queue on and then waited forever (measured: both workers of a killed map still there 5 s later), and an
    evaluation process waited on its pipe, whose parent's end it had inherited."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _may_fork() -> bool:
    """Whether this process may fork workers: not itself a worker, not daemonic, fork exists here, and this is the
    main thread (a fork copies only the calling thread, and a lock another thread holds stays held in the copy)."""
    return not (
        _IN_WORKER
        or multiprocessing.current_process().daemon
        or "fork" not in multiprocessing.get_all_start_methods()
        or threading.current_thread() is not threading.main_thread()
    )


def parallel_map(function: Callable[[T], R], items: Sequence[T]) -> list[R]:
    """[function(item) for item in items], on up to `workers()` forked processes (in order)."""
    n = min(workers(), len(items))
    if n <= 1 or not _may_fork():
        return [function(item) for item in items]
    global _TASK
    _TASK = function
    try:
        context = multiprocessing.get_context("fork")
        with ProcessPoolExecutor(n, mp_context=context, initializer=_end_with, initargs=(os.getpid(),)) as pool:
            return list(pool.map(_call, items))
    finally:
        _TASK = None


def _serve(conn, parent: int, function: Callable) -> None:
    """A forked process of `_EvaluationMap`: ``[function(x) for x in xs]`` for each list xs received (an
    exception goes back in place of the list and is raised in the parent), until the parent ends it or is gone
    (`_end_with`).  Ctrl-C is the parent's to handle: it ends its processes."""
    global _IN_WORKER
    _IN_WORKER = True
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _end_with(parent)
    try:
        while True:
            xs = conn.recv()
            try:
                out = [function(x) for x in xs]
            except Exception as exc:  # noqa: BLE001 (raised again in the parent, where it is handled)
                out = exc
            conn.send(out)
    except (EOFError, OSError):  # the parent is gone
        pass


class _EvaluationMap:
    """``map(fun, xs)`` as scipy's ``workers`` calls it, for a ``fun`` that wraps `function` (scipy's wrappers
    of a ``least_squares`` residual function only fix the array type and shape): in this process until one call
    took `POOL_AFTER_S`; then xs is cut in `processes` consecutive parts, this process evaluates the first and
    forked processes, which inherit ``function``, the others (one pipe each: no pool threads, no pickled
    function)."""

    def __init__(self, function: Callable, processes: int):
        self.function, self.processes = function, processes
        self._peers: list = []

    def __call__(self, fun: Callable, xs: Iterable) -> list:
        xs = list(xs)
        if self._peers:
            return self._shared(fun, xs)
        t0 = time.perf_counter()
        out = [fun(x) for x in xs]
        if len(xs) > 1 and time.perf_counter() - t0 >= POOL_AFTER_S:
            self._fork()
        return out

    def _fork(self) -> None:
        context = multiprocessing.get_context("fork")
        for _ in range(self.processes - 1):
            mine, theirs = context.Pipe()
            process = context.Process(target=_serve, args=(theirs, os.getpid(), self.function), daemon=True)
            process.start()
            theirs.close()
            self._peers.append((process, mine))

    def _shared(self, fun: Callable, xs: list) -> list:
        """The parts' evaluations in order; every process's answer is read before an error is raised (the first
        part's, as in order), so that no answer is left in a pipe."""
        parts = np.array_split(np.arange(len(xs)), self.processes)
        for (_, conn), part in zip(self._peers, parts[1:]):
            conn.send([xs[i] for i in part])
        try:
            mine = [fun(xs[i]) for i in parts[0]]
        except Exception as exc:  # noqa: BLE001 (raised below, after the other parts are read)
            mine = exc
        answers = [mine] + [conn.recv() for _, conn in self._peers]
        for answer in answers:
            if isinstance(answer, Exception):
                raise answer
        return [np.atleast_1d(f) for answer in answers for f in answer]

    def close(self) -> None:
        """End the processes (they hold nothing to clean up; one may be mid-evaluation)."""
        for process, conn in self._peers:
            process.terminate()
            process.join()
            conn.close()
        self._peers = []


@contextmanager
def evaluation_map(function: Callable[[np.ndarray], np.ndarray]) -> Iterator[Callable | None]:
    """Within: a map-like callable for ``scipy.optimize.least_squares(function, ..., workers=...)`` that evaluates
    a forward-difference Jacobian's columns on up to `workers()` forked processes, once one Jacobian took
    `POOL_AFTER_S` here.  The same numbers as in this process: each column is the deterministic ``function`` of
    its theta, and scipy counts the evaluations itself.  None where this process may not fork or one process is
    asked (scipy then maps here).  The processes end with the context."""
    n = workers()
    if n <= 1 or not _may_fork():
        yield None
        return
    mapper = _EvaluationMap(function, n)
    try:
        yield mapper
    finally:
        mapper.close()
