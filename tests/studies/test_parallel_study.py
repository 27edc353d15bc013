"""The studies' tasks (tune's search chains, train's folds and final fits, the decoupled study's (DOF, model) units)
give the same bytes whatever runs them: serially (``AUVID_JOBS=1``), in the forked process pool (the default: every
usable core) and on a Dask cluster. Every file the tune, train and decoupled stages write is compared, except the
ones that record time."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from pipeline import parallel
from pipeline.config import Params
from stages import decoupled as decoupled_stage
from stages import train as train_stage
from stages import tune as tune_stage
from tests.studies.helpers import coupled_store

TRIALS = {"s1": 21, "s2": 22, "s3": 23}
TIMED = {"search_trace.json", "timings.json", "timings.png"}  # wall / CPU seconds


def _params() -> Params:
    return Params(features={"test_trials": ["s3"]},
                  coupled={"folds": 3, "max_evals": 4, "max_samples": 150,
                           "models": ["rbf_svr", "wdse_svr", "fossen", "graybox_fossen"]},
                  decoupled={"folds": 3, "max_samples": 300, "gp_max_samples": 60, "curve_points": 2})


@pytest.fixture(scope="module")
def store_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("features")
    coupled_store(root, TRIALS, 30.0, _params())
    return root


def _run(store_root: Path, root: Path, scheduler: object = None) -> dict[str, bytes]:
    from pipeline.sim import load_example_vehicle

    shutil.copytree(store_root / "data/features", root / "data/features")
    vehicle, params = load_example_vehicle(), _params()
    with parallel.backend(scheduler):
        tune_stage.run(root, vehicle, params)
        train_stage.run(root, vehicle, params)
        decoupled_stage.run(root, vehicle, params)
    data = root / "data"
    return {p.relative_to(data).as_posix(): p.read_bytes() for p in sorted(data.rglob("*"))
            if p.is_file() and "features" not in p.parts and p.name not in TIMED}


def test_pool_and_dask_write_the_same_bytes_as_serial(store_root: Path, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(parallel.ENV_SCHEDULER, raising=False)
    monkeypatch.setenv(parallel.ENV_JOBS, "1")
    calls: list[tuple[int, int]] = []
    real = parallel.imap

    def spy(fn, items, *, jobs=None, **kw):  # noqa: ANN001, ANN202
        items = list(items)
        calls.append((len(items), jobs))
        return real(fn, items, jobs=jobs, **kw)

    import pipeline.studies.decoupled as decoupled
    import pipeline.studies.tasks as tasks

    real_drive = tasks.drive

    def drive_spy(coros, *, jobs, **kw):  # noqa: ANN001, ANN202
        calls.append((len(coros), jobs))
        return real_drive(coros, jobs=jobs, **kw)

    monkeypatch.setattr(tasks, "drive", drive_spy)
    monkeypatch.setattr(decoupled, "imap", spy)
    serial = _run(store_root, tmp_path / "serial")
    # tune: 3 SVR chains + 3 gray-box residual chains; train: 4 models x (3 folds + 2 fits without a training
    # trial + the final fit), each a coroutine of rounds; decoupled: 3 DOFs x 5 models
    assert calls == [(6, 1), (24, 1), (15, 1)]

    calls.clear()
    monkeypatch.setenv(parallel.ENV_JOBS, "2")
    forked: list[int] = []
    real_fork = parallel._forked_map

    def fork_spy(fn, items, jobs):  # noqa: ANN001, ANN202
        forked.append(len(items))
        return real_fork(fn, items, jobs)

    monkeypatch.setattr(parallel, "_forked_map", fork_spy)
    pooled_tasks: list[int] = []
    real_pool = parallel.local_pool

    def pool_spy(jobs):  # noqa: ANN001, ANN202  (the tune stage's rounds go to the same forked pool)
        pooled_tasks.append(jobs)
        return real_pool(jobs)

    monkeypatch.setattr(parallel, "local_pool", pool_spy)
    pooled = _run(store_root, tmp_path / "pool")
    # every stage went through the one forked pool: tune's and train's rounds, decoupled's tasks (_forked_map)
    assert calls == [(6, 2), (24, 2), (15, 2)] and forked == [15] and pooled_tasks == [2, 2, 2]

    calls.clear()
    distributed = pytest.importorskip("distributed")
    saved = dict(os.environ)  # a LocalCluster's nannies leave their pre-spawn environment in this process
    try:
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                      dashboard_address=None) as cluster:
            on_dask = _run(store_root, tmp_path / "dask", scheduler=cluster)
    finally:
        os.environ.clear()
        os.environ.update(saved)
    assert calls == [(6, -1), (24, -1), (15, -1)]

    assert any(name.endswith("wdse_svr.joblib") for name in serial)
    assert any(name.endswith("u_gp.joblib") for name in serial)
    metrics = json.loads(serial["evaluation/coupled/metrics.json"])
    assert set(metrics) == {"rbf_svr", "wdse_svr", "fossen", "graybox_fossen"}
    # Fossen's coefficient intervals (the final fit's block bootstrap) in its card, and its gray box's base's the same
    fossen = json.loads(serial["models/coupled/fossen.card.json"])["coefficient_intervals"]
    assert fossen["intervals"] and fossen["replicates"] == 200
    assert json.loads(serial["models/coupled/graybox_fossen.card.json"])["coefficient_intervals"] == fossen
    # the conformal intervals (from the folds' out-of-fold predictions, gathered in any order) are among the bytes
    assert all(0 < m[o]["final_interval_coverage"] <= 1 for m in metrics.values() for o in m)
    # and so are the fits without a training trial (any order too): each card's across-trial quantile
    card = json.loads(serial["models/coupled/wdse_svr.card.json"])
    assert all(v["trials_held_out"] == 2 and v["half_width_trials"] > 0 for v in card["interval"].values())
    for other in (pooled, on_dask):
        assert sorted(other) == sorted(serial)
        assert [name for name in serial if other[name] != serial[name]] == []
