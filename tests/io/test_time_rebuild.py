"""Time you can trust (issue 34, items 4 and 5): a time rebuilt at a rate the table's own rounded stamps deny is
refused naming the file and the rate they imply, the right rate is accepted, ``auvid inspect --vehicle`` rebuilds
as ingest does; a loose text file is a trial named after the file.

The tables are written here: a towing-tank run sampled at 7.39 Hz (4481 rows, 606 s) whose time column is
rounded to 3 significant digits (1 s steps past 100 s) or to one decimal.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import stages.ingest as stage
from pipeline import cli, layout
from pipeline.config import Params
from pipeline.errors import ConfigError, IngestError
from pipeline.ingest import ingest_log
from pipeline.io.detect import open_log
from pipeline.io.inspect import inspect_log
from pipeline.stamps import check_rebuild
from tests.io.test_ingest_stage import make_vehicle

TRUE_HZ = 7.39
N_ROWS = 4481  # 4480 intervals: 606.2 s at 7.39 Hz
T0_S = 0.02
ROUNDINGS = {"3 significant digits": lambda v: f"{float(f'{v:.3g}')}", "1 decimal": lambda v: f"{v:.1f}"}


def tank_rows(rounding: str, n: int = N_ROWS, rate_hz: float = TRUE_HZ) -> list[str]:
    """Whitespace rows ``t x r``: t rounded as named, x the row index (the answer a rebuild must keep aligned)."""
    fmt = ROUNDINGS[rounding]
    return [f"{fmt(T0_S + k / rate_hz)} {k}.0 {2 * k}.0" for k in range(n)]


def write_table(path: Path, rows: list[str]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("towing tank run 1\nzig-zag 20/20\n" + "\n".join(rows) + "\n")
    return path


def tank_vehicle(pattern: str, rate_hz: float | None) -> Any:
    stream: dict[str, Any] = {
        "file": pattern, "clock": "column",
        "csv": {"time_column": "t", "delimiter": " ", "header": False, "columns": ["t", "x", "r"], "skip_rows": 2},
        "signals": {"u_mps": {"field": "x"}, "n1_rpm": {"field": "r"}}}
    if rate_hz is not None:
        stream["time"] = {"rate_hz": rate_hz}
    return make_vehicle({"tank": stream})


# -- the check itself ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("rounding", sorted(ROUNDINGS))
def test_the_stamps_imply_the_true_rate_and_deny_a_wrong_one(rounding: str) -> None:
    stamps = np.array([round(float(r.split()[0]) * 1e9) for r in tank_rows(rounding)], dtype=np.int64)
    rows = np.arange(N_ROWS)
    wrong = check_rebuild(stamps, rows, 20.0)
    assert wrong is not None and not wrong.ok and wrong.suggested == "7.39" and wrong.rows == 4480
    assert wrong.rebuilt_s == pytest.approx(224.0) and wrong.stamps_s == pytest.approx(606.2, abs=0.5)
    right = check_rebuild(stamps, rows, TRUE_HZ)
    assert right is not None and right.ok
    # what the rounding allows at the two ends: a 1-s step (3 digits past 100 s) or 0.1-0.2 s
    assert right.allowed_s <= (1.2 if rounding == "3 significant digits" else 0.4)
    assert not check_rebuild(stamps, rows, 7.2).ok  # 2.6 % off: 16 s over the run


def test_stamps_that_carry_no_time_are_not_checked() -> None:
    rows = np.arange(50)
    assert check_rebuild(np.zeros(50, dtype=np.int64), rows, 20.0) is None
    assert check_rebuild(np.full(50, 12_500_000_000), rows, 20.0) is None
    one_step = np.where(rows < 25, 0, 10**9).astype(np.int64)
    assert check_rebuild(one_step, rows, 20.0) is None  # a single step forward: no resolution to judge by


def test_a_long_run_at_a_nominal_rate_gets_a_rate_with_enough_digits() -> None:
    """An hour at 19.998 Hz with ms stamps: 20 Hz drifts 0.36 s, and "20" would not fix it."""
    n = 72_000
    stamps = np.rint(np.arange(n) / 19.998 * 1e3).astype(np.int64) * 1_000_000
    check = check_rebuild(stamps, np.arange(n), 20.0)
    assert check is not None and not check.ok and check.suggested == "19.998"
    assert check_rebuild(stamps, np.arange(n), float(check.suggested)).ok


# -- ingest ----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("rounding", sorted(ROUNDINGS))
def test_a_wrong_rate_is_refused_naming_the_file_and_the_stamps_rate(tmp_path: Path, rounding: str) -> None:
    trial = tmp_path / "trial"
    write_table(trial / "run1.txt", tank_rows(rounding))
    with pytest.raises(IngestError) as err:
        ingest_log(trial, tank_vehicle("run*.txt", 20), source_name="trial")
    text = str(err.value)
    stamps_s = "605.98" if rounding == "3 significant digits" else "606.2"  # 0.02 .. 606 or 606.2
    assert f"time: {{rate_hz: 20}} but the stamps of trial/run1.txt advance {stamps_s} s" in text
    assert "over 4480 rows: 7.39 Hz" in text and "set rate_hz: 7.39" in text and "224 s" in text
    assert err.value.field == "time.rate_hz" and err.value.topic == "run*.txt"


@pytest.mark.parametrize("rounding", sorted(ROUNDINGS))
def test_the_right_rate_is_accepted_and_keeps_the_rows_aligned(tmp_path: Path, rounding: str) -> None:
    trial = tmp_path / "trial"
    rows = tank_rows(rounding)
    write_table(trial / "run1.txt", rows)
    out = ingest_log(trial, tank_vehicle("run*.txt", TRUE_HZ))
    t_ns = out.tables["tank"]["t_ns"].to_numpy()
    first_ns = round(float(rows[0].split()[0]) * 1e9)  # 0.02 s, or 0.0 s with one decimal
    np.testing.assert_array_equal(t_ns, first_ns + np.rint(np.arange(N_ROWS) * (1e9 / TRUE_HZ)).astype(np.int64))
    np.testing.assert_array_equal(out.tables["tank"]["u_mps"].to_numpy(), np.arange(N_ROWS))
    assert out.report["streams"]["tank"]["stamp_warnings"] == []


def test_one_log_refused_is_quarantined_every_log_refused_is_a_config_error(tmp_path: Path) -> None:
    root = tmp_path / "run"
    raw = root / layout.RAW
    write_table(raw / "run1" / "run1.txt", tank_rows("1 decimal"))
    result = stage.run(root, tank_vehicle("run*.txt", 20), Params())
    [entry] = result.quarantined
    assert entry["field"] == "time.rate_hz" and "data/raw/run1/run1.txt" in entry["reason"]
    assert "set rate_hz: 7.39" in entry["reason"] and not (root / layout.SIGNALS / "run1").exists()
    write_table(raw / "run2" / "run2.txt", tank_rows("1 decimal"))
    with pytest.raises(ConfigError, match=r"every log \(2\) fails.*7\.39 Hz"):
        stage.run(root, tank_vehicle("run*.txt", 20), Params())
    assert stage.run(root, tank_vehicle("run*.txt", TRUE_HZ), Params()).quarantined == []


# -- inspect --vehicle -----------------------------------------------------------------------------------------
def ship_config(tmp_path: Path, rate_hz: float) -> Path:
    path = tmp_path / f"ship{rate_hz:g}.yaml"
    path.write_text(json.dumps(tank_vehicle("run*.txt", rate_hz).model_dump(mode="json", exclude_defaults=True)))
    return path


def test_inspect_with_the_vehicle_rebuilds_as_ingest_does(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    log = write_table(tmp_path / "trial" / "run1.txt", tank_rows("3 significant digits"))
    plain = inspect_log(log)["topics"]["run1.txt"]
    assert "duplicates" in {w["check"] for w in plain["stamp_warnings"]}  # 1-s steps past 100 s

    assert cli.main(["inspect", str(log.parent), "--vehicle", str(ship_config(tmp_path, TRUE_HZ)), "--json"]) == 0
    item = json.loads(capsys.readouterr().out)["topics"]["run1.txt"]
    assert item["stamp_warnings"] == [] and item["time_rate_hz"] == TRUE_HZ
    assert item["rate_hz"] == pytest.approx(TRUE_HZ) and item["duration_s"] == pytest.approx(4480 / TRUE_HZ)
    assert "times rebuilt at 7.39 Hz" in item["stamps"]["checked"]

    assert cli.main(["inspect", str(log.parent), "--vehicle", str(ship_config(tmp_path, 20))]) == 0
    out = capsys.readouterr().out
    assert "run1.txt: WARNING rate_mismatch: time: {rate_hz: 20} but the stamps of run1.txt" in out
    assert "7.39 Hz" in out and "Remedy: set rate_hz: 7.39" in out


# -- a loose text file is a trial ------------------------------------------------------------------------------
def test_a_loose_text_file_is_a_trial_named_after_the_file(tmp_path: Path) -> None:
    root = tmp_path / "run"
    write_table(root / layout.RAW / "zigzag01.txt", tank_rows("1 decimal", n=200))
    result = stage.run(root, tank_vehicle("*.txt", TRUE_HZ), Params())
    assert result.quarantined == [] and result.summary["trials_written"] == ["zigzag01"]
    report = json.loads(layout.ingest_report_path(root, "zigzag01").read_text())
    assert report["source_file"] == "data/raw/zigzag01.txt" and report["streams"]["tank"]["file"] == "zigzag01.txt"
    assert report["streams"]["tank"]["count"] == 200


def test_a_loose_gzip_table_opens_as_text(tmp_path: Path) -> None:
    import gzip

    path = tmp_path / "run3.csv.gz"
    path.write_bytes(gzip.compress(b"t,x\n0,1\n0.1,2\n"))
    assert open_log(path).format == "csv" and list(open_log(path).topics()) == ["run3.csv.gz"]


@pytest.mark.parametrize("name,content,match", [
    ("run1.txt", b"t x\n\x00\x01\x02\x03", "named as text but the file holds binary data"),
    ("run1", b"t x\n0 1\n", "unknown format"),
    ("run1.mcap", b"t x\n0 1\n", "unknown format"),
])
def test_a_file_refused_says_a_text_trial_is_one_file_or_one_directory(tmp_path: Path, name: str, content: bytes,
                                                                       match: str) -> None:
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(IngestError, match=match) as err:
        open_log(path)
    assert "a text trial is one file (.csv, .tsv, .txt, .dat, .log, .gz) or one directory" in str(err.value)


def test_a_pattern_that_misses_the_loose_file_says_what_file_names(tmp_path: Path) -> None:
    path = write_table(tmp_path / "zigzag01.txt", tank_rows("1 decimal", n=20))
    with pytest.raises(IngestError, match=r"no CSV file matches 'run\*\.txt'; available: \['zigzag01.txt'\] "
                                          r"\(a text trial is one file"):
        ingest_log(path, tank_vehicle("run*.txt", None))
