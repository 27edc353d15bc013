"""Where joblib work runs: local processes by default, a Dask cluster on request.

Every fan-out in the pipeline (per-trial stages, CV folds, hyperparameter search) goes through joblib. This
module picks joblib's backend once, at the top of a run:

* default: joblib's own local process pool (``loky``), ``n_jobs`` = the number of usable cores;
* ``--scheduler ADDRESS`` on the CLI, or the environment variable ``AUVID_SCHEDULER``: a
  ``dask.distributed.Client`` connected to ``ADDRESS`` and joblib's ``"dask"`` backend, so that the same
  ``Parallel(...)`` calls run on the cluster's workers.

Library code does not care which: it calls ``joblib.Parallel(n_jobs=n_jobs())`` (or scikit-learn's
``n_jobs=n_jobs()``) inside whatever backend is active. ``parallel_backend(scheduler)`` is the context
manager the CLI enters; ``backend()`` is the same with the scheduler taken from the environment.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import joblib

from pipeline.errors import ConfigError

log = logging.getLogger(__name__)

ENV_SCHEDULER = "AUVID_SCHEDULER"
ENV_JOBS = "AUVID_JOBS"
CONNECT_TIMEOUT_S = 10.0

T = TypeVar("T")
R = TypeVar("R")

_active: dict[str, Any] = {"scheduler": None, "client": None}


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


def usable_cpus() -> int:
    """The number of CPUs this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def active_scheduler() -> str | None:
    """Address of the Dask scheduler the current backend uses, or None for local processes."""
    return _active["scheduler"]


def _connect(scheduler: Any) -> Any:
    try:
        from dask.distributed import Client
    except ImportError:
        raise ConfigError("a Dask scheduler was requested but dask.distributed is not installed; "
                          "install the extra: pip install -e '.[dask]'") from None
    if hasattr(scheduler, "scheduler_address"):  # a LocalCluster or similar object
        return Client(scheduler)
    try:
        return Client(str(scheduler), timeout=f"{CONNECT_TIMEOUT_S}s")
    except OSError as err:
        raise ConfigError(f"cannot reach Dask scheduler {scheduler!r}: {err}") from None


@contextmanager
def parallel_backend(scheduler: Any = None) -> Iterator[str]:
    """Run the enclosed joblib work locally (``scheduler=None``) or on the Dask cluster at ``scheduler``.

    ``scheduler`` is an address (``tcp://host:8786``) or a cluster object with ``scheduler_address``.
    Yields the joblib backend name (``"loky"`` or ``"dask"``). Nested calls with the same scheduler reuse
    the outer client.
    """
    if scheduler is None or scheduler == "":
        previous = dict(_active)
        _active.update(scheduler=None, client=None)
        try:
            with joblib.parallel_config(backend="loky"):
                yield "loky"
        finally:
            _active.update(previous)
        return
    address = getattr(scheduler, "scheduler_address", scheduler)
    if _active["scheduler"] == address and _active["client"] is not None:
        yield "dask"
        return
    client = _connect(scheduler)
    previous = dict(_active)
    _active.update(scheduler=address, client=client)
    log.info("joblib work goes to the Dask cluster at %s", address)
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


def pmap(fn: Callable[[T], R], items: Iterable[T], *, jobs: int | None = None) -> list[R]:
    """``[fn(x) for x in items]`` through joblib in the active backend, results in input order.

    A single item (or ``jobs == 1`` locally) runs inline: no process start-up for nothing.
    """
    items = list(items)
    jobs = n_jobs() if jobs is None else jobs
    if len(items) <= 1 or (jobs == 1 and _active["scheduler"] is None):
        return [fn(x) for x in items]
    if _active["scheduler"] is None:
        jobs = min(jobs, len(items))
    return list(joblib.Parallel(n_jobs=jobs)(joblib.delayed(fn)(x) for x in items))
