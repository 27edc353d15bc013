"""A run directory after a killed command and beside a second one: every stage removes the temporaries a killed
writer of its own left (and no one else's), and one command writes a run root at a time (a second exits 2 naming
the root and the holder's pid; the lock goes when the holder ends, however it ends)."""

from __future__ import annotations

import fcntl
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from pipeline import cli, layout
from pipeline.config import Params
from pipeline.errors import RunRootBusy
from pipeline.rootlock import LOCK_FILE, run_root_lock
from pipeline.sim import load_example_vehicle
from pipeline.tableio import atomic_path
from stages import common
from tests.cli.helpers import FakeDag, make_run_dir

REPO = Path(__file__).resolve().parents[2]


_DEAD_WRITERS: list[object] = []  # kept referenced: a collected atomic_path would clean up after itself


def killed_write(target: Path) -> Path:
    """The temporary a writer killed inside :func:`atomic_path` leaves beside ``target`` (the real name)."""
    writing = atomic_path(target)
    tmp = writing.__enter__()  # never left: the process "died" here
    _DEAD_WRITERS.append(writing)
    tmp.write_bytes(b"half a file")
    return tmp


# Where each stage writes (its own outputs); per-trial stages run for trial01 and must spare trial02's.
OWN = {
    "ingest": ["data/signals/quarantine.json"],
    "sync": ["data/synced/trial01.parquet"],
    "differentiate": ["data/kinematics/trial01.parquet", "data/kinematics/trial01.estimation.json"],
    "derive": ["data/derived/trial01.parquet"],
    "features": ["data/features/vehicle=dagon/trial=trial01/part-0.parquet"],
    "tune": ["data/models/coupled/hyperparameters.json", "data/evaluation/coupled/table2.md"],
    "train": ["data/models/coupled/svr.joblib", "data/evaluation/coupled/table3.json"],
    "decoupled": ["data/models/decoupled/u_svr.joblib", "data/evaluation/decoupled/metrics.json"],
    "simulate": ["data/simulation/trial01/free_run.parquet", "data/simulation/metrics.json"],
    "report": ["reports/report.html", "reports/plots/ingest_rates.json"],
}
SIBLING = {"sync": "data/synced/trial02.parquet", "differentiate": "data/kinematics/trial02.parquet",
           "derive": "data/derived/trial02.parquet",
           "features": "data/features/vehicle=dagon/trial=trial02/part-0.parquet"}


@pytest.mark.parametrize("stage", common.STAGE_ORDER)
def test_each_stage_removes_its_own_stale_temporaries(tmp_path: Path, stage: str) -> None:
    root = tmp_path / "run"
    stale = [killed_write(root / target) for target in OWN[stage]]
    spared = [killed_write(root / SIBLING[stage])] if stage in SIBLING else []
    not_ours = root / Path(OWN[stage][0]).parent / ".notes.tmp"  # not the temp-name pattern
    not_ours.write_text("a user's file")
    module = common.load_stage(stage)
    kwargs = {"trial": "trial01"} if stage in SIBLING else {}
    try:
        module.run(root, load_example_vehicle(), Params(), **kwargs)
    except Exception:  # noqa: BLE001 - an empty run root: the stage may stop for want of input, after its cleanup
        pass
    assert [p for p in stale if p.exists()] == []
    assert all(p.exists() for p in spared) and not_ours.exists()


def test_a_killed_per_trial_stage_leaves_nothing_after_a_full_rerun(tmp_path: Path) -> None:
    root = tmp_path / "run"
    stale = [killed_write(layout.synced_path(root, t)) for t in ("trial01", "gone")]
    try:
        common.load_stage("sync").run(root, load_example_vehicle(), Params())
    except Exception:  # noqa: BLE001
        pass
    assert [p for p in stale if p.exists()] == []


def hold_lock(root: Path, *, fork_child: bool = False) -> tuple[subprocess.Popen[str], list[int]]:
    """Another process holding the run root's lock (and, with ``fork_child``, a forked child of it); returns the
    holder and the pids it printed once the lock was taken."""
    script = textwrap.dedent(f"""
        import os, sys, time
        from pipeline.rootlock import run_root_lock
        with run_root_lock({str(root)!r}):
            pids = [os.getpid()]
            if {fork_child!r}:
                ready, tell = os.pipe()
                child = os.fork()
                if child == 0:  # os.fork ran the at-fork handlers before it returned here
                    os.write(tell, b"x")
                    time.sleep(60)
                    os._exit(0)
                os.read(ready, 1)  # the child is past its at-fork handlers before anyone looks at the lock
                pids.append(child)
            print(*pids, flush=True)
            sys.stdin.read()
    """)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-c", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True, env=env, cwd=REPO)
    assert proc.stdout is not None
    pids = [int(p) for p in proc.stdout.readline().split()]
    assert pids, "the holder did not start"
    return proc, pids


def lock_is_free(root: Path) -> bool:
    with open(root / LOCK_FILE, "a+") as handle:
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return False
        fcntl.flock(handle.fileno(), fcntl.LOCK_UN)
        return True


def test_a_second_command_on_a_held_root_exits_2_naming_root_and_holder(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    dag = FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path)
    base = ["--root", str(root), "--vehicle", str(root / "vehicle.yaml"), "-q"]
    holder, (pid,) = hold_lock(root)
    try:
        assert cli.main(["ingest", *base]) == 2
        err = capsys.readouterr().err
        assert str(root) in err and f"pid {pid}" in err and "another auvid command" in err
        assert cli.main(["sync", *base, "--trial", "trial01"]) == 2  # one trial: the same lock
        assert common.stage_main("ingest", dag.modules["ingest"].run,
                                 ["--root", str(root), "--vehicle", str(root / "vehicle.yaml")]) == 2
        assert dag.calls == []  # nothing ran
        assert not (root / layout.SIGNALS).exists()
    finally:
        holder.communicate("")
    assert cli.main(["ingest", *base]) == 0  # the holder ended: the lock went with it
    assert dag.calls == [("ingest", None)]


def test_the_lock_is_released_after_a_run_and_after_an_exception(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    FakeDag(fail_at="sync").install(monkeypatch)
    root = make_run_dir(tmp_path)
    base = ["--root", str(root), "--vehicle", str(root / "vehicle.yaml"), "-q"]
    assert cli.main(["ingest", *base]) == 0
    assert lock_is_free(root)
    with pytest.raises(RuntimeError, match="injected crash"):
        cli.main(["run", *base])  # a bug in a stage: the exception leaves, the lock does not stay
    assert lock_is_free(root)
    with pytest.raises(RunRootBusy), run_root_lock(root):  # held in this process: re-entrant, not busy...
        with run_root_lock(root):
            assert not lock_is_free(root)
            raise RunRootBusy("stand-in for any error", file=root)
    assert lock_is_free(root)


def test_kill_9_releases_the_lock_even_with_forked_workers_alive(tmp_path: Path) -> None:
    root = tmp_path / "run"
    holder, (pid, child) = hold_lock(root, fork_child=True)
    try:
        assert not lock_is_free(root)
        os.kill(pid, signal.SIGKILL)
        holder.wait(timeout=30)
        os.kill(child, 0)  # the forked worker outlives its parent...
        assert lock_is_free(root)  # ...and does not keep the lock
    finally:
        for p in (pid, child):
            try:
                os.kill(p, signal.SIGKILL)
            except ProcessLookupError:
                pass
