"""The text limits as params keys (issue 36): ``ingest.text_max_bytes``, ``text_max_lines`` and
``text_max_line_bytes`` reach the text reader; a file beyond a lowered limit is quarantined naming the file and
the limit, the others are ingested as before."""

from __future__ import annotations

from pathlib import Path

import pytest

import stages.ingest as stage
from pipeline import layout
from pipeline.config import Params, load_params
from pipeline.config.params import IngestParams
from pipeline.errors import ConfigError, IngestError
from pipeline.ingest import ingest_log
from pipeline.io import text
from tests.io.test_ingest_stage import CSV_STREAMS, N, make_vehicle, raw_root, write_csv_trial


def test_the_params_defaults_are_the_readers() -> None:
    p = IngestParams()
    assert text.TextLimits(p.text_max_bytes, p.text_max_lines, p.text_max_line_bytes) == text.TextLimits()


@pytest.mark.parametrize(("ingest", "says"), [
    ({"text_max_lines": 5}, "more than 5 lines"),
    ({"text_max_bytes": 1024}, "more than 1024 bytes of text"),
])
def test_a_lower_limit_from_params_is_honoured_by_the_ingest_stage(tmp_path: Path, ingest: dict[str, int],
                                                                   says: str) -> None:
    root = tmp_path / "run"
    for trial, n in (("trial01", 60), ("trial02", 65)):
        write_csv_trial(root / layout.RAW / trial, n=n)
    assert all((root / layout.RAW / t / "fog.csv").stat().st_size > 1024 for t in ("trial01", "trial02"))
    result = stage.run(root, make_vehicle(CSV_STREAMS), Params.model_validate({"ingest": ingest}))
    assert result.exit_code == 1
    by_trial = {e["trial"]: e for e in result.quarantined}
    assert set(by_trial) == {"trial01", "trial02"}
    for trial, entry in by_trial.items():
        assert says in entry["reason"] and entry["file"] == f"data/raw/{trial}", (trial, entry)


def test_a_limit_between_two_files_sizes_keeps_the_smaller(tmp_path: Path) -> None:
    """trial01 has N + 1 lines, trial02 N + 6: a limit of N + 3 lines keeps trial01 and quarantines trial02."""
    root = raw_root(tmp_path)
    result = stage.run(root, make_vehicle(CSV_STREAMS), Params.model_validate(
        {"ingest": {"text_max_lines": N + 3}}))
    assert [e["trial"] for e in result.quarantined] == ["trial02"]
    assert f"more than {N + 3} lines" in result.quarantined[0]["reason"]
    assert layout.stream_path(root, "trial01", "fog").exists()
    assert not layout.signals_dir(root, "trial02").exists()


def test_a_line_limit_reaches_the_reader(tmp_path: Path) -> None:
    root = raw_root(tmp_path)
    long = root / layout.RAW / "trial01" / "fog.csv"
    long.write_text(long.read_text() + "1," + "9" * 3000 + ",0\n")
    with pytest.raises(IngestError, match="fog.csv: text file holds a line longer than 2048 bytes"):
        ingest_log(long.parent, make_vehicle(CSV_STREAMS), text_limits=text.TextLimits(max_line_bytes=2048))
    assert not ingest_log(long.parent, make_vehicle(CSV_STREAMS), text_limits=text.TextLimits(max_line_bytes=4096),
                          checksum="none").quarantine  # the same line under a higher limit: read


@pytest.mark.parametrize(("key", "value"), [("text_max_bytes", 2**40), ("text_max_bytes", 0),
                                            ("text_max_lines", 0), ("text_max_lines", 2**63),
                                            ("text_max_line_bytes", 10), ("text_max_line_bytes", 2**40)])
def test_text_limits_beyond_their_bounds_are_refused(tmp_path: Path, key: str, value: int) -> None:
    path = tmp_path / "params.yaml"
    path.write_text(f"ingest:\n  {key}: {value}\n")
    with pytest.raises(ConfigError) as info:
        load_params(path)
    assert info.value.field == f"ingest.{key}" and str(path) in str(info.value)
