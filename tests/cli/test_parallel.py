"""Scale-out: the same joblib work gives the same result locally and on a Dask cluster."""

from __future__ import annotations

import joblib
import pytest
from distributed import LocalCluster

from pipeline import parallel
from pipeline.errors import ConfigError


def _square_plus(x: int) -> int:
    return x * x + 1


def _job() -> list[int]:
    return joblib.Parallel(n_jobs=parallel.n_jobs())(joblib.delayed(_square_plus)(i) for i in range(12))


def test_default_is_local_processes(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(parallel.ENV_SCHEDULER, raising=False)
    with parallel.backend() as name:
        assert name == "loky"
        assert parallel.active_scheduler() is None
        assert parallel.n_jobs() >= 1
        assert parallel.pmap(_square_plus, [1, 2, 3], jobs=1) == [2, 5, 10]


def test_dask_cluster_gives_same_result_as_local(monkeypatch: pytest.MonkeyPatch) -> None:
    with parallel.parallel_backend(None):
        local = _job()
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        monkeypatch.setenv(parallel.ENV_SCHEDULER, cluster.scheduler_address)
        with parallel.backend() as name:
            assert name == "dask"
            assert parallel.active_scheduler() == cluster.scheduler_address
            assert parallel.n_jobs() == -1
            remote = _job()
            mapped = parallel.pmap(_square_plus, range(12))
            backend_name = joblib.parallel.get_active_backend()[0].__class__.__name__
    assert backend_name == "DaskDistributedBackend"
    assert remote == local == mapped
    assert parallel.active_scheduler() is None


def test_unreachable_scheduler_is_a_config_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(parallel, "CONNECT_TIMEOUT_S", 1.0)
    with pytest.raises(ConfigError, match="cannot reach Dask scheduler"):
        with parallel.parallel_backend("tcp://127.0.0.1:9"):
            pass


def test_bad_jobs_env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(parallel.ENV_JOBS, "many")
    with pytest.raises(ConfigError, match="AUVID_JOBS"):
        parallel.n_jobs()
    monkeypatch.setenv(parallel.ENV_JOBS, "3")
    assert parallel.n_jobs() == 3


def test_auvid_run_fans_trials_out_on_the_cluster(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    from pipeline import cli
    from tests.cli.helpers import FakeDag, make_run_dir

    dag = FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path, ("trial01", "trial02", "trial03"))
    seen_backends = []
    original = parallel.pmap

    def spy(fn, items, **kw):  # noqa: ANN001, ANN202
        seen_backends.append(parallel.active_scheduler())
        return original(fn, items, **kw)

    monkeypatch.setattr(parallel, "pmap", spy)
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        code = cli.main(["run", "--root", str(root), "--vehicle", str(root / "vehicle.yaml"), "-q",
                         "--scheduler", cluster.scheduler_address, "--to", "derive"])
    assert code == 0
    assert seen_backends == [cluster.scheduler_address] * 3  # sync, differentiate, derive
    assert sorted(t for s, t in dag.calls if s == "derive") == ["trial01", "trial02", "trial03"]
    assert sorted(p.name for p in (root / "data/derived").iterdir()) == [f"trial0{i}.parquet" for i in (1, 2, 3)]


# ------------------------------------------------------------------ --scheduler local[:N], the work threshold


@pytest.mark.parametrize(("text", "expected"), [
    (None, None), ("", None), ("  ", None), ("local", ("local", None)), ("LOCAL", ("local", None)),
    ("local:3", ("local", 3)), ("tcp://10.0.0.1:8786", "tcp://10.0.0.1:8786"),
])
def test_scheduler_values(text: str | None, expected: object) -> None:
    assert parallel.parse_scheduler(text) == expected


@pytest.mark.parametrize("text", ["local:0", "local:-2", "local:many", "local:"])
def test_bad_local_worker_count_is_a_config_error(text: str) -> None:
    with pytest.raises(ConfigError, match="local:N"):
        parallel.parse_scheduler(text)


def test_scheduler_local_starts_a_local_cluster_and_closes_it() -> None:
    with parallel.parallel_backend("local:1") as name:
        address = parallel.active_scheduler()
        assert name == "dask" and address is not None and address.startswith("tcp://")
        from dask.distributed import get_client

        assert len(get_client().scheduler_info()["workers"]) == 1
        assert parallel.pmap(abs, [-1, -2, 3]) == [1, 2, 3]
    assert parallel.active_scheduler() is None
    with pytest.raises(ConfigError, match="cannot reach"):  # the cluster is gone with the context
        with parallel.parallel_backend(address):
            pass


def test_auvid_run_scheduler_local_n(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``auvid run --scheduler local:2`` asks for a 2-worker LocalCluster and fans out there (an in-process
    cluster stands in: the fake stages cannot be imported by worker processes)."""
    from pipeline import cli
    from tests.cli.helpers import FakeDag, make_run_dir

    FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path, ("trial01", "trial02"))
    started, seen = [], []
    original = parallel.pmap

    def local_cluster(workers):  # noqa: ANN001, ANN202
        started.append(workers)
        return LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None)

    def spy(fn, items, **kw):  # noqa: ANN001, ANN202
        seen.append(parallel.active_scheduler())
        return original(fn, items, **kw)

    monkeypatch.setattr(parallel, "_local_cluster", local_cluster)
    monkeypatch.setattr(parallel, "pmap", spy)
    code = cli.main(["run", "--root", str(root), "--vehicle", str(root / "vehicle.yaml"), "-q",
                     "--scheduler", "local:2", "--to", "derive"])
    assert code == 0 and started == [2]
    assert len(seen) == 3 and all(s is not None and s.startswith("inproc://") for s in seen)
    assert parallel.active_scheduler() is None


@pytest.mark.parametrize("scheduler", ["local", "tcp://127.0.0.1:8786"])
def test_scheduler_without_dask_exits_2_naming_the_extra(tmp_path, monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture[str], scheduler: str) -> None:
    import sys

    from pipeline import cli
    from tests.cli.helpers import FakeDag, make_run_dir

    dag = FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path)
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # import dask.distributed -> ImportError
    code = cli.main(["run", "--root", str(root), "--vehicle", str(root / "vehicle.yaml"), "--scheduler", scheduler])
    assert code == 2
    assert "pip install -e '.[dask]'" in capsys.readouterr().err
    assert dag.calls == []  # before any stage


def _boom(*_a: object, **_k: object) -> None:
    raise AssertionError("a process pool was started")


def test_small_work_runs_serially_large_work_in_the_pool(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(parallel.ENV_POOL_MIN_BYTES, raising=False)
    calls = []
    with parallel.parallel_backend(None):
        real = joblib.Parallel
        monkeypatch.setattr(joblib, "Parallel", _boom)
        small = parallel.POOL_MIN_BYTES - 1
        assert parallel.pmap(_square_plus, [1, 2, 3], jobs=2, work_bytes=small,
                             on_done=lambda *a: calls.append(a)) == [2, 5, 10]
        assert calls == [(1, 3, 0), (2, 3, 1), (3, 3, 2)]
        monkeypatch.setattr(joblib, "Parallel", real)
        calls.clear()
        assert parallel.pmap(_square_plus, [1, 2, 3], jobs=2, work_bytes=parallel.POOL_MIN_BYTES,
                             on_done=lambda *a: calls.append(a)) == [2, 5, 10]
        assert [d for d, _, _ in calls] == [1, 2, 3] and sorted(i for _, _, i in calls) == [0, 1, 2]
    assert not parallel.pool_pays(3, parallel.POOL_MIN_BYTES - 1, 2)
    assert parallel.pool_pays(3, parallel.POOL_MIN_BYTES, 2)
    assert parallel.pool_pays(3, None, 2)  # unknown work: the pool, as before
    assert not parallel.pool_pays(3, None, 1) and not parallel.pool_pays(1, None, 8)
    monkeypatch.setenv(parallel.ENV_POOL_MIN_BYTES, "0")
    assert parallel.pool_pays(2, 0, 2)


def test_threshold_is_ignored_on_a_cluster_the_user_asked_for() -> None:
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        with parallel.parallel_backend(cluster.scheduler_address):
            assert parallel.pool_pays(2, 0, 1)


def test_per_trial_stages_on_small_trials_start_no_pool_and_report_each_trial(
        tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    from stages import common
    from tests.cli.helpers import FakeDag, make_run_dir

    dag = FakeDag().install(monkeypatch)
    monkeypatch.setenv(parallel.ENV_JOBS, "2")  # a pool would be allowed; the input is too small for one
    monkeypatch.delenv(parallel.ENV_POOL_MIN_BYTES, raising=False)
    monkeypatch.setattr(joblib, "Parallel", _boom)
    root = make_run_dir(tmp_path, ("trial01", "trial02", "trial03"))
    seen_jobs = []
    ingest = dag.modules["ingest"]
    plain_run = ingest.run

    def ingest_run(root, vehicle, params, logs=None, progress=None, n_jobs=1):  # noqa: ANN001, ANN202
        seen_jobs.append(n_jobs)
        return plain_run(root, vehicle, params, logs=logs, progress=progress)

    monkeypatch.setattr(ingest, "run", ingest_run)
    calls: dict[str, list[tuple]] = {}
    for stage in ("ingest", "sync", "differentiate", "derive"):
        rec = calls.setdefault(stage, [])
        common.run_stage(stage, root, None, None, progress=lambda *a, rec=rec: rec.append(a))  # type: ignore[arg-type]
    assert seen_jobs == [1]  # ingest: three tiny logs, no pool
    for stage in ("sync", "differentiate", "derive"):
        assert calls[stage] == [(0, 3), (1, 3, "trial01"), (2, 3, "trial02"), (3, 3, "trial03")], stage
    assert sorted(t for s, t in dag.calls if s == "derive") == ["trial01", "trial02", "trial03"]


def test_trial_input_bytes(tmp_path) -> None:
    from pipeline import layout
    from stages import common

    (tmp_path / "data/signals/t1").mkdir(parents=True)
    (tmp_path / "data/signals/t1/imu.parquet").write_bytes(b"x" * 100)
    for path, n in ((layout.synced_path(tmp_path, "t1"), 10), (layout.kinematics_path(tmp_path, "t1"), 7)):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"x" * n)
    assert [common.trial_input_bytes(s, tmp_path, "t1") for s in ("sync", "differentiate", "derive")] == [100, 110, 7]
    assert common.trial_input_bytes("sync", tmp_path, "missing") == 0


def test_quiet_run_on_a_local_cluster_prints_one_line(tmp_path) -> None:
    """-q means one summary line, also with the scheduler and nannies of a LocalCluster logging in the process
    (a real ``auvid`` process: dask sets up its log handlers at import)."""
    import subprocess
    import sys
    from pathlib import Path

    from pipeline.sim import example_vehicle_path, generate_trial, load_example_vehicle, write_trial

    raw = tmp_path / "data/raw"
    raw.mkdir(parents=True)
    write_trial(generate_trial(load_example_vehicle(), 3.0, seed=1), "mcap", raw / "t1.mcap")
    auvid = Path(sys.executable).with_name("auvid")
    done = subprocess.run([str(auvid), "run", "--root", str(tmp_path), "--vehicle", str(example_vehicle_path()),
                           "-q", "--scheduler", "local:1", "--to", "ingest"], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert len(done.stdout.splitlines()) == 1 and done.stderr == "", (done.stdout, done.stderr)


# ------------------------------------------------------------------ the forked local pool


def _fail_on_two(x: int) -> int:
    if x == 2:
        raise ValueError("item two failed")
    return x


def _worker_threads(_: int) -> tuple[list[int], int]:
    import pyarrow
    from threadpoolctl import threadpool_info

    return [pool["num_threads"] for pool in threadpool_info()], pyarrow.cpu_count()


def test_forked_pool_passes_a_worker_error_on_and_leaves_no_worker(monkeypatch: pytest.MonkeyPatch) -> None:
    import multiprocessing

    monkeypatch.delenv(parallel.ENV_POOL_START, raising=False)
    before = set(multiprocessing.active_children())  # loky workers earlier tests left for reuse
    with parallel.parallel_backend(None):
        assert parallel._fork_pool_available()
        with pytest.raises(ValueError, match="item two failed"):
            parallel.pmap(_fail_on_two, range(8), jobs=2)
    assert set(multiprocessing.active_children()) - before == set()


def test_forked_workers_run_one_blas_and_one_arrow_thread_each(monkeypatch: pytest.MonkeyPatch) -> None:
    """The workers are the parallelism: a BLAS or Arrow pool per worker as wide as the machine oversubscribes it."""
    import numpy  # noqa: F401  (its BLAS is loaded here, so the workers inherit it)
    import pyarrow  # noqa: F401

    monkeypatch.delenv(parallel.ENV_POOL_START, raising=False)
    with parallel.parallel_backend(None):
        seen = parallel.pmap(_worker_threads, range(4), jobs=2)
    for blas_threads, arrow_threads in seen:
        assert blas_threads and set(blas_threads) == {1}
        assert arrow_threads == 1


def _pid(_: int) -> int:
    import os
    import time

    time.sleep(0.05)  # both workers get items
    return os.getpid()


def test_forked_workers_are_kept_from_fan_out_to_fan_out_inside_a_local_backend(
        monkeypatch: pytest.MonkeyPatch) -> None:
    import multiprocessing

    monkeypatch.delenv(parallel.ENV_POOL_START, raising=False)
    before = set(multiprocessing.active_children())
    with parallel.parallel_backend(None):
        first = set(parallel.pmap(_pid, range(6), jobs=2))
        second = set(parallel.pmap(_pid, range(6), jobs=2))
        assert first == second and len(first) == 2  # the next stage finds the same two workers
        parallel.release_workers()
        assert set(multiprocessing.active_children()) - before == set()
        third = set(parallel.pmap(_pid, range(6), jobs=2))
        assert not third & first
    assert set(multiprocessing.active_children()) - before == set()  # the context's end ends them
    once = set(parallel.pmap(_pid, range(4), jobs=2))  # outside a backend: the fan-out's own workers
    assert not once & third and set(multiprocessing.active_children()) - before == set()


def _malloc_trim() -> str | None:
    import os

    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


def test_local_cluster_workers_keep_glibcs_memory() -> None:
    """``--scheduler local``'s workers start without Dask's MALLOC_TRIM_THRESHOLD_=65536, under which every trial's
    large arrays faulted their pages in again (twice the CPU per trial); the rest of Dask's worker environment (one
    BLAS thread) stays."""
    from dask.distributed import Client

    cluster = parallel._local_cluster(1)
    try:
        with Client(cluster) as client:
            env = next(iter(client.run(_malloc_trim).values()))
            blas = next(iter(client.run(lambda: __import__("os").environ.get("OPENBLAS_NUM_THREADS")).values()))
    finally:
        cluster.close()
    assert env is None and blas == "1"


def _housekeeping() -> tuple[object, object]:
    import dask

    return dask.config.get("distributed.worker.profile.enabled"), dask.config.get("distributed.admin.tick.interval")


def test_local_cluster_workers_do_not_sample_their_tasks_stacks() -> None:
    """``--scheduler local``'s workers neither profile their task thread every 10 ms (a dashboard's view, and the
    run has none) nor wake their event loop every 20 ms: on a machine whose cores are all workers, that work took
    the cores and the GIL from the tasks. The run's own Dask configuration is left as it was."""
    import dask
    from dask.distributed import Client

    before = dask.config.get("distributed.worker.profile.enabled")
    cluster = parallel._local_cluster(1)
    try:
        with Client(cluster) as client:
            profile, tick = next(iter(client.run(_housekeeping).values()))
    finally:
        cluster.close()
    assert profile is False and tick == "500ms"
    assert dask.config.get("distributed.worker.profile.enabled") == before


def _row_sum(X: object, k: int) -> float:
    return float(X[k].sum() + k)


def _row_sums(X: object, rows: int):  # noqa: ANN202  (a coroutine of pipeline.rounds: one round of tasks)
    return (yield [(_row_sum, (X, k)) for k in range(rows)])


def test_an_array_every_task_holds_goes_to_the_cluster_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """A search's rows, held by each of its fit tasks (:mod:`pipeline.rounds`), are scattered to the cluster once
    per object; an array below ``SCATTER_BYTES`` rides inside its tasks. Results are the same either way."""
    import numpy as np
    from distributed import Client

    from pipeline import rounds

    X = np.arange(64 * 1000, dtype=float).reshape(1000, 64)  # 512 kB
    small = X[:4].copy()  # 2 kB
    scattered: list[object] = []
    real = Client.scatter

    def counting(self, data, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
        scattered.append(data)
        return real(self, data, *args, **kwargs)

    monkeypatch.setattr(Client, "scatter", counting)
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        monkeypatch.setenv(parallel.ENV_SCHEDULER, cluster.scheduler_address)
        with parallel.backend():
            got = rounds.drive([_row_sums(X, 8), _row_sums(small, 4)], jobs=-1)
    assert got == [[_row_sum(X, k) for k in range(8)], [_row_sum(small, k) for k in range(4)]]
    assert sum(s is X for s in scattered) == 1 and not any(s is small for s in scattered)


def test_starting_a_local_cluster_leaves_this_process_environment_as_it_was() -> None:
    """Dask's nannies write their pre-spawn environment (MALLOC_TRIM_THRESHOLD_, one BLAS thread) into the
    process that starts them and leave it there: every process started later (the next cluster's workers, a
    forked pool's) would inherit it. ``--scheduler local`` puts the environment back."""
    import os

    before = dict(os.environ)
    cluster = parallel._local_cluster(1)
    try:
        assert dict(os.environ) == before
    finally:
        cluster.close()
    assert "MALLOC_TRIM_THRESHOLD_" not in os.environ or "MALLOC_TRIM_THRESHOLD_" in before
