"""Independent fits on several processes: the diagnosis' candidates of a round and its held-out refits, an
effect fit's screened starts and raced refinements, a rate-dependent candidate's refinements.

Each candidate effect of a diagnosis round is fitted on the same base, independently of
the others (`fitter.diagnosis.rounds.candidate_round`), each recording's
held-out refit is independent of the others' (`fitter.diagnosis.held_out`), and so are the screened starts
and the raced refinements of ``duhem fit --effects`` (`fitter.identification.effects_fit`) and the starts and
global restarts of a rate-dependent candidate (`fitter.identification.fit`):
`parallel_map` runs them on up to `workers()` processes.  The processes are
forked, so they inherit the experiment and the fits made so far; only the
item (an effect name, a recording index, a start) goes to a process and only its
result (a `Fit`, a `RefineResult`) comes back.  Every fit is deterministic, so the result
is the same on any number of processes (tested).  A map inside a worker, or in a daemonic process (a Dask
worker of ``duhem batch``, which may not have children), runs in that process.

`evaluation_map` does the same for the evaluations of one forward-difference Jacobian in
`fitter.identification.refine` (the map its optimiser's ``workers`` argument takes), taken from both ends of the list
(`_EvaluationMap`): the evaluations of the columns are independent, so on two cores a fit whose Jacobians cost most
of its time takes about half the wall time, with the same result to the last digit (each column is the same
function of the same theta in whichever process).

`side_by_side` runs two computations at once, one in a forked process: the order search's two chains of
candidates (`fitter.identification.search`), each rate-dependent order beside the next rate-independent one.  The
maps inside either lane use only the cores no lane holds (`_take_cores`), so that two lanes on two cores start no
third process until one lane ends and gives its core to the other.

Within a process, a fit's BLAS runs on one thread (`one_blas_thread`): its matrices are small.
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
from threadpoolctl import ThreadpoolController

__all__ = [
    "WORKERS_ENV",
    "evaluation_map",
    "one_blas_thread",
    "one_blas_thread_to_exit",
    "parallel_map",
    "side_by_side",
    "workers",
]

WORKERS_ENV = "DUHEM_WORKERS"
"""Environment variable: the number of processes of the independent fits (default: the machine's cores)."""

T = TypeVar("T")
R = TypeVar("R")
POOL_AFTER_S = 0.02
"""`evaluation_map` forks its processes once one map of evaluations took this long in this process: below it a
fork (some milliseconds, measured 7-10 ms for a process of 300 MB) and the transfers cost about what they save."""

_TASK: Callable | None = None
_IN_WORKER = False
_BLAS: ThreadpoolController | None = None
_HELD = False
"""Whether this process holds the one-thread limit: inside a `one_blas_thread` block, or after one whose limit was
kept (`_KEEP`).  A forked process inherits it."""
_KEEP = False
"""Whether the next `one_blas_thread` block keeps its limit to this process's end (`one_blas_thread_to_exit`)."""
_SPARE = None
"""Inside `side_by_side` (in both of its processes): the shared count of the cores that neither lane holds, which a
lane's maps take and give back (`_take_cores`); None outside."""


def workers() -> int:
    """Processes for the independent fits: ``DUHEM_WORKERS`` when set (a whole number >= 1), else the cores."""
    value = os.environ.get(WORKERS_ENV, "").strip()
    if value:
        try:
            return max(1, int(value))
        except ValueError:
            raise ValueError(f"{WORKERS_ENV}={value!r}: give a whole number of processes >= 1") from None
    return os.cpu_count() or 1


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """Within: BLAS on one thread (threadpoolctl): the matrices of a fit are small, so BLAS's worker threads only
    cost CPU (OpenBLAS's idle threads spin) and change the rounding from run to run.  The libraries are looked up
    once per process, at the first call (`threadpoolctl.threadpool_limits` looks them up at every call, measured
    2 ms: every loaded library's path resolved): numpy's and scipy's BLAS, which the modules that hold a block
    have loaded by then.  A forked process inherits the lookup.

    Within a block already holding the limit, in this process or in the process that forked this one from inside
    it, a block changes nothing: OpenBLAS's thread count setter starts its thread pool where none runs (in a
    forked process), and its threads then spin at every later setting, on a core the other processes need
    (measured in `duhem reproduce-paper`'s pool: 0.05-0.07 s of a core per pool process)."""
    global _HELD
    if _HELD:
        yield
        return
    limit = _controller().limit(limits=1, user_api="blas")
    _HELD = True
    if _KEEP:  # never restored (`one_blas_thread_to_exit`)
        yield
        return
    with limit:  # as a context it also hands OpenBLAS's control back at its end (other threads may set it then)
        try:
            yield
        finally:
            _HELD = False


def one_blas_thread_to_exit() -> None:
    """From the next `one_blas_thread` block on, BLAS stays on one thread to this process's end: that block's end
    restores nothing.  For a process that runs one job and ends (the ``duhem`` executable, `fitter.cli.console`).

    A block's end restores the thread count.  Where a fork inside the block shut OpenBLAS's thread pool down (its
    fork handler does so in the parent), the restore starts the pool again, one thread per library, and each new
    thread spins before it sleeps: 0.1 s of a core in all, measured, taken from the process's last work and its
    exit.  The limit is set at the block, not here: where the executable starts, scipy's BLAS is not loaded yet,
    and a lookup now would miss it."""
    global _KEEP
    _KEEP = True


def _controller() -> ThreadpoolController:
    """This process's BLAS libraries, looked up at the first call (a forked process inherits the lookup)."""
    global _BLAS
    if _BLAS is None:
        _BLAS = ThreadpoolController()
    return _BLAS


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
    """[function(item) for item in items], on up to `workers()` forked processes (in order).  In a lane of
    `side_by_side` the items run in this process, one after the other, until a core is spare; the items left then
    go to the processes."""
    if not _may_fork():
        return [function(item) for item in items]
    out: list[R] = []
    while len(out) < len(items):
        extra = _take_cores(min(workers(), len(items) - len(out)) - 1)
        if not extra:
            out.append(function(items[len(out)]))
            continue
        try:
            out += _pool_map(function, items[len(out) :], 1 + extra)
        finally:
            _give_back(extra)
    return out


def _pool_map(function: Callable[[T], R], items: Sequence[T], processes: int) -> list[R]:
    """[function(item) for item in items] on `processes` forked processes, this one waiting."""
    global _TASK
    _TASK = function
    try:
        context = multiprocessing.get_context("fork")
        with ProcessPoolExecutor(processes, mp_context=context, initializer=_end_with, initargs=(os.getpid(),)) as pool:
            return list(pool.map(_call, items))
    finally:
        _TASK = None


def _take_cores(want: int) -> int:
    """How many processes beyond this one a map may run now, at most `want` (>= 0; the caller keeps it within
    `workers()`): all of them outside `side_by_side`; in one of its lanes, the cores no lane holds (`_SPARE`),
    taken until `_give_back`."""
    if want <= 0 or _SPARE is None:
        return max(want, 0)
    with _SPARE.get_lock():
        taken = min(want, _SPARE.value)
        _SPARE.value -= taken
    return taken


def _give_back(cores: int) -> None:
    """Return cores taken with `_take_cores` (nothing to return outside `side_by_side`)."""
    if _SPARE is not None and cores:
        with _SPARE.get_lock():
            _SPARE.value += cores


class _Raised:
    """An exception of the forked lane of `side_by_side`, carried back to be raised in its parent."""

    def __init__(self, error: Exception):
        self.error = error


def _lane(conn, parent: int, function: Callable) -> None:
    """The forked lane of `side_by_side`: ``function()`` (or its exception) sent back, its core given back first
    so that the other lane's next map can take it.  Ctrl-C is the parent's to handle: it ends this process."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _end_with(parent)
    try:
        result = function()
    except Exception as error:  # noqa: BLE001 (raised again in the parent)
        result = _Raised(error)
    _give_back(1)
    try:
        conn.send(result)
    except Exception as error:  # noqa: BLE001 (an answer that does not pickle)
        conn.send(_Raised(RuntimeError(f"the forked lane's answer could not be sent back: {error}")))


def side_by_side(first: Callable[[], T], second: Callable[[], R]) -> tuple[T, R]:
    """(first(), second()), computed at the same time: `first` in a forked process (its answer pickled back),
    `second` in this one.  Each lane holds one core; when one ends, the other's next map takes its core
    (`parallel_map`'s next item, `evaluation_map`'s next Jacobian), so that two dependent chains of fits keep both
    cores busy (the order search of `fitter.identification.search`).  In turn, first then second, where this
    process may not fork, on one process, or inside a lane.  The answers are those of the turn: every fit is
    deterministic, whichever process runs it.  An exception of `first` is raised before one of `second`, as in
    turn.  `first` runs in another process: it reports nothing to this process's displays (`fitter.progress`)."""
    global _SPARE
    if workers() < 2 or _SPARE is not None or not _may_fork():
        return first(), second()
    context = multiprocessing.get_context("fork")
    _SPARE = context.Value("i", workers() - 2)
    mine, theirs = context.Pipe(duplex=False)
    lane = context.Process(target=_lane, args=(theirs, os.getpid(), first))
    failed: Exception | None = None
    try:
        lane.start()
        theirs.close()
        try:
            answer = second()
        except Exception as error:  # noqa: BLE001 (raised after first's, as in turn)
            answer, failed = None, error
        finally:
            _give_back(1)
        try:
            forked = mine.recv()
        except EOFError:
            raise RuntimeError("the forked lane of the search ended without an answer") from None
    except BaseException:
        lane.terminate()
        raise
    finally:
        lane.join()
        mine.close()
        _SPARE = None
    if isinstance(forked, _Raised):
        raise forked.error
    if failed is not None:
        raise failed
    return forked, answer


def _take(ends, back: bool) -> int | None:
    """The next index of a map's evaluations (`_EvaluationMap`): ``ends`` holds the first and the last index not
    yet taken; this process takes the first, the forked ones (``back``) the last.  None once they have met."""
    with ends.get_lock():
        first, last = ends[0], ends[1]
        if first > last:
            return None
        if back:
            ends[1] = last - 1
            return last
        ends[0] = first + 1
        return first


def _serve(conn, parent: int, function: Callable, ends) -> None:
    """A forked process of `_EvaluationMap`: for each list xs received, ``function(xs[k])`` for the indices k it
    takes from the back (`_take`), sent back as (k, value) pairs (an exception in place of a value, the last pair,
    raised in the parent), until the parent ends it or is gone (`_end_with`).  Ctrl-C is the parent's to handle:
    it ends its processes."""
    global _IN_WORKER
    _IN_WORKER = True
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _end_with(parent)
    try:
        while True:
            xs, out = conn.recv(), []
            while (k := _take(ends, back=True)) is not None:
                try:
                    out.append((k, function(xs[k])))
                except Exception as exc:  # noqa: BLE001 (raised again in the parent, where it is handled)
                    out.append((k, exc))
                    break
            conn.send(out)
    except (EOFError, OSError):  # the parent is gone
        pass


class _EvaluationMap:
    """``map(fun, xs)`` as scipy's ``workers`` calls it, for a ``fun`` that wraps `function` (scipy's wrappers
    of `refine`'s residual function only fix the array type and shape): in this process until one call
    took `POOL_AFTER_S` (and, in a lane of `side_by_side`, until a core is spare); then this process evaluates
    xs from the front and forked processes, which inherit ``function``, from the back, each taking the next one
    as it is free (`_take`: one pipe each, no pool threads, no pickled function).  Columns differ in cost (an
    effect fit's base columns against its effects' columns, which the memo of
    `fitter.identification.output_error` makes cheap or dear in turn), so that fixed halves kept one process
    waiting on the other (measured on piezo.best's 30-column Jacobians: 6.7 s in this process's half, 10.1 s for
    the maps); taken from the two ends, each process keeps to one kind, and its memo holds the other kind's part
    at theta."""

    def __init__(self, function: Callable, processes: int):
        self.function, self.processes = function, processes
        self._peers: list = []

    def __call__(self, fun: Callable, xs: Iterable) -> list:
        xs = list(xs)
        if self._peers:
            return self._shared(fun, xs)
        t0 = time.perf_counter()
        out = [fun(x) for x in xs]
        if len(xs) > 1 and time.perf_counter() - t0 >= POOL_AFTER_S and (extra := _take_cores(self.processes - 1)):
            self._fork(extra)
        return out

    def _fork(self, extra: int) -> None:
        """Fork `extra` processes, which hold the cores `_take_cores` gave until `close`."""
        context = multiprocessing.get_context("fork")
        self._ends = context.Array("q", 2)
        for _ in range(extra):
            mine, theirs = context.Pipe()
            args = (theirs, os.getpid(), self.function, self._ends)
            process = context.Process(target=_serve, args=args, daemon=True)
            process.start()
            theirs.close()
            self._peers.append((process, mine))

    def _shared(self, fun: Callable, xs: list) -> list:
        """The evaluations in order, taken from the two ends (class docstring); every process's answer is read
        before an error is raised (that of the lowest index, as in order), so that no answer is left in a pipe."""
        self._ends[0], self._ends[1] = 0, len(xs) - 1
        for _, conn in self._peers:
            conn.send(xs)
        values, failed = [None] * len(xs), []
        while (k := _take(self._ends, back=False)) is not None:
            try:
                values[k] = fun(xs[k])
            except Exception as exc:  # noqa: BLE001 (raised below, after the other processes' answers are read)
                failed.append((k, exc))
                break
        for _, conn in self._peers:
            for k, value in conn.recv():
                if isinstance(value, Exception):
                    failed.append((k, value))
                else:
                    values[k] = value
        if failed:
            raise min(failed, key=lambda kv: kv[0])[1]
        return [np.atleast_1d(v) for v in values]

    def close(self) -> None:
        """End the processes (they hold nothing to clean up; one may be mid-evaluation)."""
        for process, conn in self._peers:
            process.terminate()
            process.join()
            conn.close()
        _give_back(len(self._peers))
        self._peers = []


@contextmanager
def evaluation_map(function: Callable[[np.ndarray], np.ndarray]) -> Iterator[Callable | None]:
    """Within: a map-like callable for the ``workers`` argument of `refine`'s optimiser, that evaluates
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
