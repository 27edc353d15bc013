"""Work that decides in rounds: coroutines that ask for independent tasks, and one driver that runs many of them.

A hyperparameter search is sequential in its decisions but not in its work: each round it asks for a batch of
independent tasks (its candidates' fold fits, a GP's proposals) and decides the next round from their results.
Written as a generator that yields a list of ``(fn, args)`` and receives their results in the same order (or the
first task's exception, thrown in), it leaves where the tasks run to :func:`drive`:

* ``jobs == 1``: inline, one task after the other, in the order asked;
* more: the rounds of every coroutine given go to one executor at once (the run's forked pool, joblib's loky pool
  where fork is not available, or the Dask cluster of the active backend), and a coroutine's next round is asked
  for as soon as its last task ends, so that a stage's critical path is its longest chain of rounds, not the sum
  of its searches.

Every task runs under one BLAS / OpenMP thread wherever it runs, and a coroutine sees its results in the order it
asked for them: serial, pool and cluster give the same bits. Each task's time goes to
:func:`pipeline.parallel.record_task`, named ``"<label> r<round> #<k>"`` with the round before as its dependency
(``bench/span.py`` takes the critical path through them).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Generator, Sequence
from typing import Any, TypeVar

from pipeline import parallel

__all__ = ["Coroutine", "Task", "drive", "gather", "run_inline"]

R = TypeVar("R")
Task = tuple[Callable[..., Any], tuple[Any, ...]]
Coroutine = Generator[list[Task], list[Any], R]

#: arrays at least this large go to a Dask cluster once per object (scattered), not once per task
SCATTER_BYTES = 64_000


#: the worker processes whose BLAS / OpenMP pools are down to one thread for good (threadpoolctl costs ~2 ms a call:
#: once per worker, not once per task)
_ONE_THREAD: set[int] = set()


def call_timed(fn: Callable[..., Any], args: tuple[Any, ...], limited: bool = False) -> dict[str, Any]:
    """``fn(*args)`` under one BLAS / OpenMP thread (a worker's first task limits its process for good;
    ``limited``: the caller holds the limit), with its start, wall and CPU time and the process's id."""
    if not limited and os.getpid() not in _ONE_THREAD:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
        _ONE_THREAD.add(os.getpid())
    start, cpu0, t0 = time.time(), time.process_time(), time.perf_counter()
    result = fn(*args)
    return {"result": result, "start": start, "wall_s": time.perf_counter() - t0,
            "cpu_s": time.process_time() - cpu0, "pid": os.getpid()}


def call_many(calls: list[Task]) -> list[dict[str, Any]]:
    """:func:`call_timed` of each ``(fn, args)`` in order: several tasks of a round as one executor task."""
    return [call_timed(fn, args) for fn, args in calls]


def _record(stage: str, label: str, round_: int, timed: Sequence[dict[str, Any]]) -> None:
    deps = [f"{label} r{round_ - 1}"] if round_ else []
    for k, t in enumerate(timed):
        parallel.record_task(stage, f"{label} r{round_} #{k}", start=t["start"], wall_s=t["wall_s"],
                             cpu_s=t["cpu_s"], pid=t["pid"], deps=deps)


def gather(coros: Sequence[Coroutine[Any]]) -> Coroutine[list[Any]]:
    """Coroutines side by side as one: each round asks for the next round of every one not yet ended, together,
    and hands each its own results; returns their values in order. Their rounds then cost the longest one's, not
    the sum. A task's exception ends all of them (it cannot be told whose it was) and propagates."""
    results: list[Any] = [None] * len(coros)
    requests: dict[int, list[Task]] = {}

    def step(index: int, sent: Any) -> None:
        try:
            requests[index] = coros[index].send(sent)
        except StopIteration as stop:
            results[index] = stop.value
            requests.pop(index, None)

    for index in range(len(coros)):
        step(index, None)
    while requests:
        order = sorted(requests)
        flat = [task for index in order for task in requests[index]]
        try:
            answers = yield flat
        except BaseException:
            for coro in coros:
                coro.close()
            raise
        at = 0
        for index in order:
            n = len(requests[index])
            step(index, answers[at:at + n])
            at += n
    return results


def run_inline(coro: Coroutine[R], stage: str = "", label: str = "") -> R:
    """Run one coroutine to its end, its tasks inline in the order asked; its return value. With a ``stage``,
    each task's time is recorded (:func:`pipeline.parallel.record_task`)."""
    return drive([coro], jobs=1, stage=stage, labels=[label])[0]


def drive(coros: Sequence[Coroutine[Any]], *, jobs: int, stage: str = "", labels: Sequence[str] | None = None,
          on_done: Callable[[int, Any], None] | None = None) -> list[Any]:
    """Run every coroutine to its end; their return values in order. ``jobs`` (1: inline, one coroutine after
    the other; more, or -1 on a Dask cluster: every coroutine's rounds on one executor, see the module's
    docstring). ``on_done(index, value)`` as each coroutine ends. ``stage``: record each task's time under it
    (nothing when empty). An exception a coroutine does not handle cancels what has not started and propagates."""
    labels = list(labels) if labels is not None else [str(k) for k in range(len(coros))]
    results: list[Any] = [None] * len(coros)
    if jobs == 1 or not coros:
        from threadpoolctl import threadpool_limits

        with threadpool_limits(1):  # this process's pools, given back after
            for index, coro in enumerate(coros):
                results[index] = _inline(coro, stage, labels[index])
                if on_done is not None:
                    on_done(index, results[index])
        return results
    with _executor(jobs) as (submit, wait_any, cancel):
        waiting: dict[Any, tuple[int, list[int]]] = {}  # future -> (coroutine, positions in its round)
        rounds: dict[int, dict[str, Any]] = {}

        def advance(index: int, sent: Any = None, error: BaseException | None = None) -> None:
            while True:
                try:
                    if error is not None:
                        request = coros[index].throw(error)
                    elif sent is None:
                        request = next(coros[index])
                    else:
                        request = coros[index].send(sent)
                except StopIteration as stop:
                    results[index] = stop.value
                    rounds.pop(index, None)
                    if on_done is not None:
                        on_done(index, stop.value)
                    return
                state = rounds.setdefault(index, {"round": -1})
                state.update(round=state["round"] + 1, timed=[None] * len(request), left=len(request))
                if request:
                    for group in submit.groups(len(request)):
                        waiting[submit([request[k] for k in group])] = (index, group)
                    return
                sent, error = [], None  # an empty round: answered at once

        try:
            for index in range(len(coros)):
                advance(index)
            while waiting:
                for future in wait_any(list(waiting)):
                    if future not in waiting:  # its round was ended by another task's exception
                        continue
                    index, group = waiting.pop(future)
                    state = rounds[index]
                    try:
                        for k, timed in zip(group, future.result(), strict=True):
                            state["timed"][k] = timed
                    except BaseException as err:  # the task's own exception, thrown into its coroutine
                        for other in [f for f, (i, _) in waiting.items() if i == index]:
                            waiting.pop(other)
                            other.cancel()
                        advance(index, error=err)
                        continue
                    state["left"] -= len(group)
                    if state["left"] == 0:
                        if stage:
                            _record(stage, labels[index], state["round"], state["timed"])
                        advance(index, [t["result"] for t in state["timed"]])
        except BaseException:
            cancel(list(waiting))
            for coro in coros:
                coro.close()
            raise
    return results


def _inline(coro: Coroutine[Any], stage: str, label: str) -> Any:
    sent: Any = None
    error: BaseException | None = None
    round_ = 0
    while True:
        try:
            request = coro.throw(error) if error is not None else coro.send(sent)
        except StopIteration as stop:
            return stop.value
        error, timed = None, []
        for fn, args in request:
            try:
                timed.append(call_timed(fn, args, limited=True))
            except Exception as err:  # the task's own exception, thrown into its coroutine as a pool would
                error = err
                break
        if error is None:
            if stage:
                _record(stage, label, round_, timed)
            sent = [t["result"] for t in timed]
        round_ += 1


class _executor:  # noqa: N801  (a context manager used as a function)
    """``(submit, wait_any(futures) -> done futures, cancel(futures))`` on the active backend: the Dask cluster's
    client, else the run's forked pool (or a loky pool); ``submit(calls)`` sends a group of a round's tasks
    (``submit.groups(n)``) as one executor task."""

    def __init__(self, jobs: int) -> None:
        self.jobs = jobs
        self.scattered: dict[int, tuple[Any, Any]] = {}

    def __enter__(self) -> tuple[_executor, Callable[..., Any], Callable[..., Any]]:
        import concurrent.futures as cf

        self.client = parallel.active_client()
        self.local = None
        if self.client is not None:
            self.pool = self.client.get_executor(pure=False)
            self.threads = max(1, sum(self.client.nthreads().values()))
        else:
            self.local = parallel.local_pool(self.jobs)
            self.pool = self.local.__enter__()

        def wait_any(futures: list[Any]) -> set[Any]:
            return cf.wait(futures, return_when=cf.FIRST_COMPLETED).done

        def cancel(futures: list[Any]) -> None:
            for future in futures:
                future.cancel()

        return self, wait_any, cancel

    def groups(self, n: int) -> list[list[int]]:
        """A round's ``n`` tasks as executor tasks: one each locally; on a cluster, about two per worker thread
        (a Dask task costs a few ms of scheduling, more than many of a search's fits)."""
        size = 1 if self.client is None else max(1, -(-n // (2 * self.threads)))
        return [list(range(k, min(n, k + size))) for k in range(0, n, size)]

    def __call__(self, calls: list[Task]) -> Any:
        """Submit ``calls`` (a group of :meth:`groups`) as one executor task; its future."""
        if self.client is not None:
            calls = [(fn, tuple(self._ship(a) for a in args)) for fn, args in calls]
        return self.pool.submit(call_many, calls)

    def _ship(self, value: Any) -> Any:
        """A large array as a reference to its copy on the cluster (sent once per object); a dict's values too."""
        if isinstance(value, dict):
            return {k: self._ship(v) for k, v in value.items()}
        nbytes = getattr(value, "nbytes", 0)
        if not isinstance(nbytes, int) or nbytes < SCATTER_BYTES:
            return value
        key = id(value)
        if key not in self.scattered:  # the object is kept with its future: its id stays its own
            self.scattered[key] = (value, self.client.scatter(value, hash=False))
        return self.scattered[key][1]

    def __exit__(self, *exc: Any) -> bool | None:
        self.scattered.clear()
        if self.local is not None:
            return self.local.__exit__(*exc)
        return None
