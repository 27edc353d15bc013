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
    from fakestages import FakeDag, make_run_dir

    from pipeline import cli

    dag = FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path, ("trial01", "trial02", "trial03"))
    seen_backends = []
    original = parallel.pmap

    def spy(fn, items, *, jobs=None):  # noqa: ANN001, ANN202
        seen_backends.append(parallel.active_scheduler())
        return original(fn, items, jobs=jobs)

    monkeypatch.setattr(parallel, "pmap", spy)
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        code = cli.main(["run", "--root", str(root), "--vehicle", str(root / "vehicle.yaml"), "-q",
                         "--scheduler", cluster.scheduler_address, "--to", "derive"])
    assert code == 0
    assert seen_backends == [cluster.scheduler_address] * 3  # sync, differentiate, derive
    assert sorted(t for s, t in dag.calls if s == "derive") == ["trial01", "trial02", "trial03"]
    assert sorted(p.name for p in (root / "data/derived").iterdir()) == [f"trial0{i}.parquet" for i in (1, 2, 3)]
