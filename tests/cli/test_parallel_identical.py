"""The per-trial fan-out writes the same bytes as a serial run: every file under ``data/`` after ``ingest`` ...
``derive``, serially (``AUVID_JOBS=1``) and in a process pool (the default forked workers, and joblib's loky
workers, the fallback where fork is not available), whatever the input size (``AUVID_POOL_MIN_BYTES=0``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline import parallel

STAGES = ("ingest", "sync", "differentiate", "derive")


@pytest.fixture(scope="module")
def raw_logs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from pipeline.sim import generate_trial, load_example_vehicle, write_trial

    raw = tmp_path_factory.mktemp("logs")
    vehicle = load_example_vehicle()
    for seed in (1, 2, 3):
        write_trial(generate_trial(vehicle, 40.0, seed=seed), "mcap", raw / f"trial0{seed}.mcap")
    return raw


def _run(root: Path, raw: Path) -> dict[str, bytes]:
    from pipeline.sim import example_vehicle_path
    from stages.common import load_configs, run_stages

    (root / "data/raw").mkdir(parents=True)
    for log in sorted(raw.iterdir()):
        (root / "data/raw" / log.name).symlink_to(log)
    vehicle, params = load_configs(root, example_vehicle_path(), None)
    with parallel.backend(None):
        results = run_stages(root, vehicle, params, STAGES)
    assert [r.stage for r in results] == list(STAGES)
    assert not any(r.quarantined for r in results)
    data = root / "data"
    return {p.relative_to(data).as_posix(): p.read_bytes() for p in sorted(data.rglob("*"))
            if p.is_file() and "raw" not in p.parts}


@pytest.mark.parametrize("start", ["fork", "loky"])
def test_pool_writes_the_same_bytes_as_serial(tmp_path: Path, raw_logs: Path, monkeypatch: pytest.MonkeyPatch,
                                              start: str) -> None:
    monkeypatch.delenv(parallel.ENV_SCHEDULER, raising=False)
    monkeypatch.setenv(parallel.ENV_JOBS, "1")
    serial = _run(tmp_path / "serial", raw_logs)

    monkeypatch.setenv(parallel.ENV_JOBS, "2")
    monkeypatch.setenv(parallel.ENV_POOL_MIN_BYTES, "0")
    monkeypatch.setenv(parallel.ENV_POOL_START, start)
    pools = []
    real = parallel._forked_map

    def spy(fn, items, jobs):  # noqa: ANN001, ANN202
        pools.append(len(items))
        return real(fn, items, jobs)

    monkeypatch.setattr(parallel, "_forked_map", spy)
    pooled = _run(tmp_path / "pool", raw_logs)

    assert pools == ([3] * len(STAGES) if start == "fork" else [])  # every stage went through the forked pool
    assert sorted(pooled) == sorted(serial)
    assert any(name.startswith("kinematics/") for name in serial)
    different = [name for name in serial if pooled[name] != serial[name]]
    assert different == []
