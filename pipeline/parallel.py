"""Where joblib work runs: local processes by default, a Dask cluster on request.

Every fan-out in the pipeline (per-trial stages, CV folds, hyperparameter search) goes through joblib. This
module picks joblib's backend once, at the top of a run:

* default: local processes, ``n_jobs`` = the number of usable cores: the per-trial and per-log fan-out of the
  stages (:func:`pmap`, :func:`imap`) forks its workers from the run's process (they start with its imports, one
  BLAS and one Arrow thread each, and are kept from stage to stage; ``AUVID_POOL_START=loky`` or a platform
  without fork: joblib's loky workers); joblib's own pool (``loky``) for the rest;
* ``--scheduler ADDRESS`` on the CLI, or the environment variable ``AUVID_SCHEDULER``: a
  ``dask.distributed.Client`` connected to ``ADDRESS`` and joblib's ``"dask"`` backend, so that the same
  ``Parallel(...)`` calls run on the cluster's workers;
* ``--scheduler local`` or ``local:N``: the same on a ``dask.distributed.LocalCluster`` started for the run
  (N worker processes, default one per usable core, one thread each) and closed after it.

A local process pool costs its start-up (forking, or for loky new interpreters importing numpy, pandas, scipy,
the pipeline) and the pickling of every task; on small inputs that is more than the work.
``pmap(..., work_bytes=...)`` therefore runs serially when the work is below :data:`POOL_MIN_BYTES` (measured by
``bench/parallel.py``). A Dask scheduler the user asked for is always used.

Library code does not care which: it calls ``joblib.Parallel(n_jobs=n_jobs())`` (or scikit-learn's
``n_jobs=n_jobs()``) inside whatever backend is active. ``parallel_backend(scheduler)`` is the context
manager the CLI enters; ``backend()`` is the same with the scheduler taken from the environment.

joblib itself (a noticeable import) is imported where a pool starts or a Dask backend is entered: a run
that fans nothing out (``auvid ingest`` of one log) never pays for it (``tests/io/test_import_budget.py``).
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

from pipeline.errors import ConfigError

log = logging.getLogger(__name__)

ENV_SCHEDULER = "AUVID_SCHEDULER"
ENV_JOBS = "AUVID_JOBS"
ENV_POOL_MIN_BYTES = "AUVID_POOL_MIN_BYTES"
ENV_POOL_START = "AUVID_POOL_START"
ENV_TASK_TRACE = "AUVID_TASK_TRACE"
CONNECT_TIMEOUT_S = 10.0
LOCAL = "local"

#: Input bytes (summed over the items of one fan-out: the logs for ingest, the trials' inputs for sync,
#: differentiate and derive) below which a local process pool does not pay and ``pmap`` runs serially.
#: A pool pays only once a stage has several seconds of serial work (its start-up and the first run of a stage's
#: code in its workers cost seconds); the value is the conservative side, for a machine shared with other work.
#: Measured with ``bench/parallel.py --sweep``: docs/benchmarks.md, "Pool threshold".
POOL_MIN_BYTES = 64_000_000

T = TypeVar("T")
R = TypeVar("R")

#: ``workers``: None outside a local backend (each fan-out forks and ends its own workers); inside one, a dict that
#: holds the forked pool the fan-outs share (``pool``, ``size``) until :func:`release_workers` or the context's end.
_active: dict[str, Any] = {"scheduler": None, "client": None, "local": None, "workers": None}


def scheduler_from_env() -> str | None:
    """The scheduler address in ``AUVID_SCHEDULER``, or None (local)."""
    value = os.environ.get(ENV_SCHEDULER, "").strip()
    return value or None


def n_jobs() -> int:
    """How many jobs a ``Parallel`` call should ask for.

    On a Dask cluster: -1 (joblib then uses every worker thread the cluster has). Locally: ``AUVID_JOBS``
    if set, else the number of CPUs this process may use.
    """
    if _active["scheduler"] is not None:
        return -1
    env = os.environ.get(ENV_JOBS, "").strip()
    if env:
        try:
            value = int(env)
        except ValueError:
            raise ConfigError(f"{ENV_JOBS} must be an integer, found {env!r}") from None
        return max(1, value)
    return usable_cpus()


def workers(requested: int | str | None) -> int:
    """The ``n_jobs`` to pass on for a params value: ``"auto"``, None or -1 -> :func:`n_jobs` (every usable core,
    ``AUVID_JOBS``, or -1 on a Dask cluster); a number of workers as it is (one on a cluster too: serial)."""
    if requested in (None, "auto", -1):
        return n_jobs()
    return int(requested)


def usable_cpus() -> int:
    """The number of CPUs this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def parse_scheduler(value: Any) -> Any:
    """What ``--scheduler`` / ``AUVID_SCHEDULER`` asks for: None (local processes), ``("local", N)`` (a
    LocalCluster of N workers; N None = one per usable core), or the value itself (an address such as
    ``tcp://host:8786``, or a cluster object). A malformed ``local:N`` is a ConfigError."""
    if value is None:
        return None
    if not isinstance(value, str):
        return value
    text = value.strip()
    if not text:
        return None
    head, sep, tail = text.partition(":")
    if head.lower() != LOCAL:
        return text
    if not sep:
        return (LOCAL, None)
    try:
        workers = int(tail)
    except ValueError:
        workers = 0
    if workers < 1:
        raise ConfigError(f"--scheduler {text!r}: expected 'local' or 'local:N' with N a positive number of "
                          f"workers, or a scheduler address such as tcp://host:8786")
    return (LOCAL, workers)


def active_scheduler() -> str | None:
    """Address of the Dask scheduler the current backend uses, or None for local processes."""
    return _active["scheduler"]


def _import_distributed() -> Any:
    try:
        import dask.distributed
    except ImportError:
        raise ConfigError("a Dask scheduler was requested but dask.distributed is not installed; "
                          "install the extra: pip install -e '.[dask]'") from None
    return dask.distributed


#: A LocalCluster's housekeeping, made rarer: each worker otherwise samples its task thread's stack every 10 ms (the
#: dashboard's profile, which a run without a dashboard never shows) and wakes its event loop every 20 ms; on a
#: machine whose cores are all workers, both take the GIL and the core from the tasks (docs/benchmarks.md, "Where
#: the LocalCluster's time went").
QUIET_CLUSTER = {"distributed.worker.profile.enabled": False, "distributed.admin.tick.interval": "500ms",
                 "distributed.admin.system-monitor.interval": "2s"}


def _local_cluster(workers: int | None) -> Any:
    """A LocalCluster of ``workers`` processes (default: one per usable core), one thread each (the work is
    numpy / libsvm and holds the GIL for long stretches), no dashboard."""
    distributed = _import_distributed()
    # The scheduler and nannies run in this process and log every start and stop at INFO through handlers of
    # their own: they follow the run's level (WARNING by default, ERROR under -q), INFO only with -v.
    root_level = logging.getLogger().getEffectiveLevel()
    logging.getLogger("distributed").setLevel(logging.INFO if root_level <= logging.DEBUG
                                              else max(logging.WARNING, root_level))
    n = workers or usable_cpus()
    log.info("starting a Dask LocalCluster with %d worker(s)", n)
    import dask

    # Dask starts its workers with MALLOC_TRIM_THRESHOLD_=65536: glibc then hands freed memory back to the system
    # at once, and a trial's next large arrays fault their pages in again (the kernel's time per trial, in
    # docs/benchmarks.md); glibc's own default keeps it
    environ = {k: v for k, v in (dask.config.get("distributed.nanny.pre-spawn-environ", None) or {}).items()
               if k != "MALLOC_TRIM_THRESHOLD_"}
    saved = dict(os.environ)  # the nannies set their pre-spawn environment in this process and leave it there
    try:
        with dask.config.set({"distributed.nanny.pre-spawn-environ": environ, **QUIET_CLUSTER}):
            return distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                            dashboard_address=None)
    finally:
        os.environ.clear()
        os.environ.update(saved)


def _connect(scheduler: Any) -> Any:
    Client = _import_distributed().Client
    if hasattr(scheduler, "scheduler_address"):  # a LocalCluster or similar object
        return Client(scheduler)
    try:
        return Client(str(scheduler), timeout=f"{CONNECT_TIMEOUT_S}s")
    except OSError as err:
        raise ConfigError(f"cannot reach Dask scheduler {scheduler!r}: {err}") from None


@contextmanager
def parallel_backend(scheduler: Any = None) -> Iterator[str]:
    """Run the enclosed joblib work locally (``scheduler=None``) or on the Dask cluster at ``scheduler``.

    ``scheduler`` is an address (``tcp://host:8786``), ``"local"`` / ``"local:N"`` (a LocalCluster started
    here and closed on exit) or a cluster object with ``scheduler_address``. Yields the joblib backend name
    (``"loky"`` or ``"dask"``). Nested calls with the same scheduler reuse the outer client.
    """
    scheduler = parse_scheduler(scheduler)
    if isinstance(scheduler, tuple):
        if _active["client"] is not None and _active.get("local") == scheduler:
            yield "dask"
            return
        dask_log = logging.getLogger("distributed")
        level = dask_log.level  # _local_cluster quiets it; given back once the cluster has logged its close
        cluster = _local_cluster(scheduler[1])
        try:
            with parallel_backend(cluster) as name:
                _active["local"] = scheduler
                yield name
        finally:
            cluster.close()
            dask_log.setLevel(level)
        return
    if scheduler is None:
        previous = dict(_active)
        _active.update(scheduler=None, client=None, local=None, workers={})
        try:
            if "joblib" not in sys.modules:  # nothing has configured joblib: its default backend is loky
                yield "loky"
            else:
                import joblib

                with joblib.parallel_config(backend="loky"):
                    yield "loky"
        finally:
            release_workers()
            _active.update(previous)
        return
    address = getattr(scheduler, "scheduler_address", scheduler)
    if _active["scheduler"] == address and _active["client"] is not None:
        yield "dask"
        return
    client = _connect(scheduler)
    previous = dict(_active)
    _active.update(scheduler=address, client=client, local=None, workers=None)
    log.info("joblib work goes to the Dask cluster at %s", address)
    import joblib

    try:
        with joblib.parallel_config(backend="dask"):
            yield "dask"
    finally:
        _active.update(previous)
        client.close()


@contextmanager
def backend(scheduler: Any = None) -> Iterator[str]:
    """Like :func:`parallel_backend`, defaulting to ``AUVID_SCHEDULER`` when no scheduler is given."""
    with parallel_backend(scheduler if scheduler is not None else scheduler_from_env()) as name:
        yield name


def pool_pays(n_items: int, work_bytes: int | None, jobs: int) -> bool:
    """Whether a fan-out of ``n_items`` over ``work_bytes`` of input should go to ``jobs`` parallel workers.

    On a Dask cluster (asked for explicitly): whenever there are two items or more. Locally: two items or more,
    more than one job, and ``work_bytes`` unknown (None) or at least :data:`POOL_MIN_BYTES`.
    """
    if n_items <= 1:
        return False
    if _active["scheduler"] is not None:
        return True
    return jobs > 1 and (work_bytes is None or work_bytes >= pool_min_bytes())


def pool_min_bytes() -> int:
    """:data:`POOL_MIN_BYTES`, or ``AUVID_POOL_MIN_BYTES`` where set (0: always the pool; the benchmark's knob)."""
    env = os.environ.get(ENV_POOL_MIN_BYTES, "").strip()
    if not env:
        return POOL_MIN_BYTES
    try:
        return max(0, int(float(env)))
    except ValueError:
        raise ConfigError(f"{ENV_POOL_MIN_BYTES} must be a number of bytes, found {env!r}") from None


def _indexed(fn: Callable[[T], R], index: int, item: T) -> tuple[int, R]:
    return index, fn(item)


def pmap(fn: Callable[[T], R], items: Iterable[T], *, jobs: int | None = None, work_bytes: int | None = None,
         on_done: Callable[[int, int, int], Any] | None = None) -> list[R]:
    """``[fn(x) for x in items]`` in the active backend (:func:`imap`), results in input order.

    ``on_done(done, total, index)`` is called as each item finishes (in completion order when parallel):
    ``done`` items finished so far, ``index`` the position in ``items`` of the one that just did.
    """
    items = list(items)
    ordered: list[Any] = [None] * len(items)
    for done, (index, result) in enumerate(imap(fn, items, jobs=jobs, work_bytes=work_bytes), start=1):
        ordered[index] = result
        if on_done is not None:
            on_done(done, len(items), index)
    return ordered


def imap(fn: Callable[[T], R], items: Iterable[T], *, jobs: int | None = None, work_bytes: int | None = None,
         in_order: bool = False) -> Iterator[tuple[int, R]]:
    """``(index, fn(items[index]))`` for every item, as each finishes (input order when inline or ``in_order``:
    a result then waits for those before it).

    (The model stages' tasks go through :mod:`pipeline.rounds`, which sends a large array to a cluster once.)

    Inline (no process start-up for nothing) for a single item, ``jobs == 1`` locally, or ``work_bytes`` (the
    input the items will read) below :data:`POOL_MIN_BYTES` locally (:func:`pool_pays`). Otherwise, locally:
    ``jobs`` worker processes forked from this one (:func:`_forked_map`; joblib's loky pool where fork is not
    available); on a Dask cluster: joblib's dask backend.
    """
    items = list(items)
    jobs = n_jobs() if jobs is None else jobs
    total = len(items)
    if not pool_pays(total, work_bytes, jobs):
        if total > 1 and work_bytes is not None and jobs > 1:
            log.debug("%d item(s), %d input bytes < %d: serial", total, work_bytes, pool_min_bytes())
        for index, item in enumerate(items):
            yield index, fn(item)
        return
    if _active["scheduler"] is None:
        jobs = min(jobs, total)
    if _active["scheduler"] is None and _fork_pool_available():
        done: Iterator[tuple[int, R]] = _forked_map(fn, items, jobs)
    else:
        import joblib

        tasks = (joblib.delayed(_indexed)(fn, i, x) for i, x in enumerate(items))
        # one task per worker in flight, the next in input order as one ends (greedy list scheduling): a cluster's
        # scheduler handed everything at once may queue a long task behind another while a worker idles (the tune
        # stage's chains differ several times in cost); callers list the costliest first where they know it
        done = joblib.Parallel(n_jobs=jobs, return_as="generator_unordered", pre_dispatch="n_jobs")(tasks)
    yield from (_input_order(done) if in_order else done)


def _input_order(done: Iterable[tuple[int, R]]) -> Iterator[tuple[int, R]]:
    """``(index, result)`` pairs given in any order, yielded by index as soon as every earlier one is there."""
    waiting: dict[int, R] = {}
    next_index = 0
    for index, result in done:
        waiting[index] = result
        while next_index in waiting:
            yield next_index, waiting.pop(next_index)
            next_index += 1


def _fork_pool_available() -> bool:
    """Whether local fan-out can fork its workers from this process (Linux; ``AUVID_POOL_START=loky`` keeps
    joblib's loky pool, the benchmark's comparison)."""
    import multiprocessing

    if os.environ.get(ENV_POOL_START, "").strip().lower() == "loky":
        return False
    return sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods()


def _forked_worker_init() -> None:
    """Set up a forked pool worker: one BLAS / OpenMP thread and one Arrow CPU thread (the workers are the
    parallelism; the parent's threads would oversubscribe the cores), and Ctrl-C left to the parent, which ends
    the workers (an idle worker would otherwise die on SIGINT with a traceback)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - scikit-learn brings it
        pass
    else:
        threadpool_limits(1)
    pyarrow = sys.modules.get("pyarrow")
    if pyarrow is not None:
        pyarrow.set_cpu_count(1)


def _forked_map(fn: Callable[[T], R], items: list[T], jobs: int) -> Iterator[tuple[int, R]]:
    """``(index, fn(items[index]))`` in completion order, from ``jobs`` worker processes forked from this one.

    A forked worker starts with everything this process has imported (the stage modules, numpy, pandas, pyarrow)
    and costs a few ms, where a spawned loky worker starts an interpreter and imports them again. Inside a local
    backend the workers are kept for the next fan-out (the next stage): a fresh process also pays for faulting
    in its heap again (docs/benchmarks.md, "Forked workers"). Any exception (a worker's, or Ctrl-C here) cancels
    what has not started and ends the workers before it propagates.
    """
    from concurrent.futures import as_completed

    with local_pool(jobs) as pool:  # an error ends the workers, as joblib does; outputs are written atomically
        futures = {pool.submit(fn, item): index for index, item in enumerate(items)}
        for future in as_completed(futures):
            yield futures[future], future.result()


def _pool(jobs: int) -> Any:
    """The forked ProcessPoolExecutor of ``jobs`` workers: the active local backend's (kept for the next fan-out),
    or a new one (its caller shuts it down when no backend keeps it: ``_active["workers"]`` is None)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    try:
        import threadpoolctl  # noqa: F401  (imported once here rather than in each worker's set-up)
    except ImportError:  # pragma: no cover - scikit-learn brings it
        pass
    shared = _active["workers"]
    if shared is not None and shared.get("pool") is not None and shared["size"] >= jobs:
        return shared["pool"]
    release_workers()
    pool = ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("fork"),
                               initializer=_forked_worker_init)
    if shared is not None:
        shared.update(pool=pool, size=jobs)
    return pool


def active_client() -> Any:
    """The Dask client of the active backend, or None (local processes)."""
    return _active["client"]


@contextmanager
def local_pool(jobs: int) -> Iterator[Any]:
    """A ``concurrent.futures`` executor of ``jobs`` local workers for tasks submitted one by one
    (:mod:`pipeline.rounds`): the forked pool the fan-outs share (:func:`_forked_map`), or joblib's reusable loky
    executor where fork is not available. An exception here ends the forked workers before it propagates."""
    if not _fork_pool_available():
        from joblib.externals.loky import get_reusable_executor

        yield get_reusable_executor(max_workers=jobs)
        return
    shared = _active["workers"]
    pool = _pool(jobs)
    try:
        yield pool
    except BaseException:
        _terminate_workers(pool)
        if shared is not None:
            shared.clear()
        raise
    finally:
        if shared is None or shared.get("pool") is not pool:
            pool.shutdown(wait=True, cancel_futures=True)


def release_workers() -> None:
    """End the forked workers the fan-outs of the active local backend share (see :func:`_forked_map`); the next
    fan-out forks new ones. ``run_stages`` calls it after the last stage that fans out: the workers would hold
    their memory through the model stages."""
    shared = _active["workers"]
    if shared:
        pool = shared.pop("pool", None)
        shared.clear()
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


def _terminate_workers(pool: Any) -> None:
    """End a ProcessPoolExecutor's workers now (``terminate_workers`` from Python 3.14 on)."""
    terminate = getattr(pool, "terminate_workers", None)
    if callable(terminate):
        terminate()
        return
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        if process.is_alive():
            process.terminate()


class timed_task:  # noqa: N801  (used as a function: ``imap(timed_task(fn, "tune"), items)``)
    """``fn`` wrapped to run under one BLAS / OpenMP thread (the workers are the parallelism, and the same thread
    count inline and in a worker gives the same bits) and to return ``{"result", "start", "wall_s", "cpu_s",
    "pid"}``: :func:`task_result` unwraps it and records the timing. Picklable when ``fn`` is."""

    def __init__(self, fn: Callable[[Any], Any], stage: str) -> None:
        self.fn = fn
        self.stage = stage

    def __call__(self, item: Any) -> dict[str, Any]:
        import time

        from threadpoolctl import threadpool_limits

        start, cpu0 = time.time(), time.process_time()
        t0 = time.perf_counter()
        with threadpool_limits(1):
            result = self.fn(item)
        return {"result": result, "start": start, "wall_s": time.perf_counter() - t0,
                "cpu_s": time.process_time() - cpu0, "pid": os.getpid()}


def task_result(timed: dict[str, Any], stage: str, name: str, deps: Iterable[str] = ()) -> Any:
    """The result of a :class:`timed_task`, its timing recorded under ``stage`` / ``name`` (:func:`record_task`)."""
    record_task(stage, name, start=timed["start"], wall_s=timed["wall_s"], cpu_s=timed["cpu_s"], pid=timed["pid"],
                deps=deps)
    return timed["result"]


def record_task(stage: str, name: str, *, start: float, wall_s: float, cpu_s: float, pid: int | None = None,
                deps: Iterable[str] = ()) -> None:
    """Append one task's timing to the file named by ``AUVID_TASK_TRACE`` (JSON lines; nothing when unset): the
    scaling benchmark's record of a run (``bench/span.py``). ``deps``: the names of the tasks it waited for, besides
    the stage's start."""
    path = os.environ.get(ENV_TASK_TRACE, "").strip()
    if not path:
        return
    import json

    line = json.dumps({"stage": stage, "task": name, "start": start, "wall_s": wall_s, "cpu_s": cpu_s, "pid": pid,
                       "deps": list(deps)})
    with open(path, "a", encoding="utf-8") as f:
        f.write(line + "\n")
