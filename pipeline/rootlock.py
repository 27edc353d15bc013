"""The run root's lock: one auvid command writes a run directory at a time.

Two commands on one run root (two ``auvid ingest``, a ``dvc repro`` beside an ``auvid run``) would remove each
other's temporaries and replace each other's outputs. :func:`run_root_lock` holds an exclusive, non-blocking
``fcntl.flock`` on ``ROOT/.auvid.lock`` for the whole command and writes its pid there; a second command gets
:class:`~pipeline.errors.RunRootBusy` (the CLI exits 2) naming the root and the holder's pid. The kernel drops
the lock when its process ends, however it ends (kill -9 too), so a stale lock file never blocks a later run.
Within one process the lock is re-entrant (``auvid run`` holds it while each stage's shell asks again). A
process forked while the lock is held (a stage's workers) closes its copy of the descriptor at once, so workers
left behind by a killed command do not keep the lock.
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from pipeline.errors import RunRootBusy

LOCK_FILE = ".auvid.lock"
_HELD: dict[Path, int] = {}  # run roots this process holds: how many holders deep
_HANDLES: dict[Path, IO[str]] = {}


def _drop_inherited() -> None:
    """In a forked child: let go of the lock files without unlocking them (the parent keeps the lock). Each
    descriptor is pointed at /dev/null rather than closed, so the child's file objects stay harmless."""
    for handle in _HANDLES.values():
        try:
            null = os.open(os.devnull, os.O_RDONLY)
            os.dup2(null, handle.fileno())
            os.close(null)
        except OSError:
            pass
    _HELD.clear()
    _HANDLES.clear()


os.register_at_fork(after_in_child=_drop_inherited)


@contextmanager
def run_root_lock(root: str | Path) -> Iterator[None]:
    """Hold ``ROOT/.auvid.lock`` for the block; RunRootBusy if another process holds it."""
    root = Path(root).resolve()
    if root in _HELD:
        _HELD[root] += 1
        try:
            yield
        finally:
            _HELD[root] -= 1
        return
    root.mkdir(parents=True, exist_ok=True)
    handle = open(root / LOCK_FILE, "a+")  # noqa: SIM115 - held for the whole command
    try:
        _take(handle, root)
        _HELD[root], _HANDLES[root] = 1, handle
        try:
            yield
        finally:
            del _HELD[root], _HANDLES[root]
            fcntl.flock(handle.fileno(), fcntl.LOCK_UN)
    finally:
        handle.close()


def _take(handle: IO[str], root: Path) -> None:
    try:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        holder = handle.read().strip() or "unknown"
        raise RunRootBusy(f"another auvid command (pid {holder}) is writing this run directory; wait for it to "
                          f"finish, or use another --root", file=root) from None
    handle.seek(0)
    handle.truncate()
    handle.write(f"{os.getpid()}\n")
    handle.flush()
