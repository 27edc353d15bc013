"""The raw log's checksum at ingest (params ``ingest.checksum``, ``auvid ingest --no-checksum``): with ``sha256`` the
provenance holds the log's real sha256; with ``none`` no hash is computed, provenance says so (``checksum: none``,
``source_sha256: null``) and the data written are the same bytes."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pyarrow as pa
import pytest
import yaml

import pipeline.ingest as ingest_mod
import stages.ingest as stage
from pipeline import cli, layout
from pipeline.cli import common as cli_common
from pipeline.cli import run as cli_run
from pipeline.config import Params, load_params
from pipeline.errors import ConfigError
from pipeline.ingest import ingest_log
from pipeline.report.build import _source_checksum
from pipeline.tableio import read_parquet
from tests.io.test_ingest_stage import CSV_STREAMS, LOG_STREAMS, _write_log, make_vehicle, write_csv_trial

KINDS = ["mcap", "ros2-sqlite3", "ros1"]
CHECKSUM_KEYS = {"source_sha256", "checksum", "file_sha256"}


def real_sha256(path: Path) -> str:
    """sha256 of the file's bytes; a bag directory: each file's relative name then its bytes, in name order."""
    if path.is_file():
        return hashlib.sha256(path.read_bytes()).hexdigest()
    digest = hashlib.sha256()
    for file in sorted(p for p in path.rglob("*") if p.is_file()):
        digest.update(str(file.relative_to(path)).encode())
        digest.update(file.read_bytes())
    return digest.hexdigest()


def without_checksum(doc: dict[str, object]) -> dict[str, object]:
    return {k: v for k, v in doc.items() if k not in CHECKSUM_KEYS}


def data_bytes(table: pa.Table) -> bytes:
    """The table's schema and columns as Arrow IPC bytes, its metadata (the provenance) left out."""
    sink = pa.BufferOutputStream()
    table = table.replace_schema_metadata(None)
    with pa.ipc.new_stream(sink, table.schema) as writer:
        writer.write_table(table)
    return sink.getvalue().to_pybytes()


# -- core ---------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", KINDS)
def test_default_records_the_logs_real_sha256(tmp_path: Path, kind: str) -> None:
    log = _write_log(kind, tmp_path)
    out = ingest_log(log, make_vehicle(LOG_STREAMS))
    assert out.report["checksum"] == "sha256" and out.report["source_sha256"] == real_sha256(log)
    for prov in out.provenance.values():
        assert prov["checksum"] == "sha256" and prov["source_sha256"] == real_sha256(log)


@pytest.mark.parametrize("kind", KINDS)
def test_none_gives_the_same_tables_and_says_none(tmp_path: Path, kind: str, monkeypatch: pytest.MonkeyPatch) -> None:
    log = _write_log(kind, tmp_path)
    vehicle = make_vehicle(LOG_STREAMS)
    hashed = ingest_log(log, vehicle)

    def refuse(path: object, *args: object) -> str:
        raise AssertionError(f"checksum none hashed {path}")

    monkeypatch.setattr(ingest_mod, "file_sha256", refuse)
    plain = ingest_log(log, vehicle, checksum="none")
    assert plain.report["checksum"] == "none" and plain.report["source_sha256"] is None
    assert without_checksum(plain.report) == without_checksum(hashed.report)
    assert sorted(plain.tables) == sorted(hashed.tables) == sorted(plain.provenance)
    for name, table in plain.tables.items():
        assert data_bytes(table) == data_bytes(hashed.tables[name])
        prov = plain.provenance[name]
        assert prov["checksum"] == "none" and prov["source_sha256"] is None
        assert without_checksum(prov) == without_checksum(hashed.provenance[name])


def test_csv_files_checksums_follow_the_option(tmp_path: Path) -> None:
    trial = tmp_path / "trial07"
    write_csv_trial(trial)
    vehicle = make_vehicle(CSV_STREAMS)
    hashed = ingest_log(trial, vehicle).provenance["fog"]
    assert hashed["file_sha256"] == real_sha256(trial / "fog.csv") and hashed["source_sha256"] == real_sha256(trial)
    plain = ingest_log(trial, vehicle, checksum="none").provenance["fog"]
    assert plain["file_sha256"] is None and plain["source_sha256"] is None and plain["checksum"] == "none"


def test_unknown_checksum_is_refused(tmp_path: Path) -> None:
    log = _write_log("mcap", tmp_path)
    with pytest.raises(ValueError, match=r"checksum must be one of \['sha256', 'none'\], got 'md5'"):
        ingest_log(log, make_vehicle(LOG_STREAMS), checksum="md5")  # type: ignore[arg-type]


def test_params_declare_the_option(tmp_path: Path) -> None:
    assert Params().ingest.checksum == "sha256"
    path = tmp_path / "params.yaml"
    path.write_text("ingest: {checksum: none}\n")
    assert load_params(path).ingest.checksum == "none"
    path.write_text("ingest: {checksum: md5}\n")
    with pytest.raises(ConfigError, match="checksum"):
        load_params(path)
    schema = json.loads((Path(__file__).resolve().parents[2] / "schemas" / "params.schema.json").read_text())
    assert schema["$defs"]["IngestParams"]["properties"]["checksum"]["enum"] == ["sha256", "none"]


# -- stage and CLI ---------------------------------------------------------------------------------------------------
def written(root: Path, trial: str) -> tuple[dict[str, tuple[bytes, dict[str, object]]], dict[str, object]]:
    """Per stream the data bytes and provenance of its Parquet file, and the trial's ingest report."""
    streams = {}
    for path in sorted(layout.signals_dir(root, trial).glob("*.parquet")):
        table, meta = read_parquet(path)
        streams[path.stem] = (data_bytes(table), meta)
    return streams, json.loads(layout.ingest_report_path(root, trial).read_text())


def test_stage_writes_the_same_data_with_checksum_none(tmp_path: Path) -> None:
    vehicle = make_vehicle(LOG_STREAMS)
    roots = {mode: tmp_path / mode for mode in ("sha256", "none")}
    for mode, root in roots.items():
        (root / layout.RAW).mkdir(parents=True)
        log = _write_log("mcap", root / layout.RAW)
        params = Params.model_validate({"ingest": {"checksum": mode}})
        assert stage.run(root, vehicle, params).exit_code == 0
    hashed, hashed_report = written(roots["sha256"], "trial5")
    plain, plain_report = written(roots["none"], "trial5")
    assert hashed_report["source_sha256"] == real_sha256(log) and hashed_report["checksum"] == "sha256"
    assert plain_report["source_sha256"] is None and plain_report["checksum"] == "none"
    assert without_checksum(plain_report) == without_checksum(hashed_report)
    assert sorted(plain) == sorted(hashed) == ["dvl", "imu", "thr"]
    for name, (data, meta) in plain.items():
        assert data == hashed[name][0]
        assert meta["checksum"] == "none" and meta["source_sha256"] is None
        assert without_checksum(meta) == without_checksum(hashed[name][1])


@pytest.mark.parametrize("flag", [[], ["--no-checksum"]])
def test_cli_no_checksum_overrides_params(tmp_path: Path, flag: list[str]) -> None:
    root = tmp_path / "run"
    log = _write_log("ros1", tmp_path)
    vfile = tmp_path / "vehicle.yaml"
    vfile.write_text(yaml.safe_dump(make_vehicle(LOG_STREAMS).model_dump(mode="json"), allow_unicode=True))
    code = cli.main(["ingest", "-q", "--root", str(root), "--vehicle", str(vfile), *flag, str(log)])
    assert code == cli_common.EXIT_OK
    _, report = written(root, "trial5")
    if flag:
        assert report["checksum"] == "none" and report["source_sha256"] is None
    else:
        assert report["checksum"] == "sha256" and report["source_sha256"] == real_sha256(log)


def test_run_takes_the_flag_too() -> None:
    parser = cli.build_parser()
    assert parser.parse_args(["run", "--no-checksum"]).checksum == "none"
    assert parser.parse_args(["ingest"]).checksum is None
    params = Params()
    assert cli_run._with_overrides(params, parser.parse_args(["ingest"])) is params
    assert cli_run._with_overrides(params, parser.parse_args(["run", "--no-checksum"])).ingest.checksum == "none"


def test_report_says_why_a_log_has_no_checksum() -> None:
    sha = "ab" * 32
    assert _source_checksum({"source_sha256": sha, "checksum": "sha256"}) == sha
    assert _source_checksum({"source_sha256": sha}, 16) == f"sha256 {sha[:16]}…"
    none = "no checksum (ingested with ingest.checksum: none)"
    assert _source_checksum({"source_sha256": None, "checksum": "none"}, 16) == none
    assert _source_checksum({}) == "no checksum recorded"
