"""Text tables under `time: {rate_hz}`: a line the reader drops (all-NaN, ragged) keeps its sample slot, a line
split in two takes one, a blank line takes none; each is counted in the ingest report with its line numbers and
warned about, and no later sample moves.

The table is sampled at 20 Hz with stamps rounded to 3 digits (the case the option exists for); column x holds
the sample index k, so the right time of every kept row is known: 0.05 s + k / 20 Hz.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pipeline.config.sources import CsvOptions
from pipeline.ingest import ingest_log
from pipeline.io.text import open_text
from pipeline.io.textlines import plan_lines
from tests.io.test_ingest_stage import make_vehicle

N = 40
PERIOD_NS = 50_000_000
FORMATS = {  # delimiter, header line, an all-NaN line as loggers write a missed sample
    "comma": (",", "t,x,r\n", ",,"),
    "whitespace": (" ", "", "NaN NaN NaN"),
}


def lines(fmt: str) -> list[str]:
    sep = FORMATS[fmt][0]
    return [sep.join((f"{float(f'{k / 20 + 0.05:.3g}')}", f"{k}.0", f"{2 * k}.0")) for k in range(N)]


def write(directory: Path, fmt: str, rows: list[str]) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "run.csv").write_text(FORMATS[fmt][1] + "\n".join(rows) + "\n")
    return directory


def vehicle(fmt: str) -> Any:
    csv: dict[str, Any] = {"time_column": "t"}
    if fmt == "whitespace":
        csv.update(delimiter=" ", header=False, columns=["t", "x", "r"])
    return make_vehicle({"tank": {"file": "run.csv", "clock": "column", "time": {"rate_hz": 20}, "csv": csv,
                                  "signals": {"u_mps": {"field": "x"}, "n1_rpm": {"field": "r"}}}})


def assert_on_time(out: Any, expected_k: list[int]) -> None:
    """Every kept sample at 0.05 s + k / 20 Hz, k read from its own x column."""
    table = out.tables["tank"]
    k = table["u_mps"].to_numpy()
    np.testing.assert_array_equal(k, expected_k)
    np.testing.assert_array_equal(table["t_ns"].to_numpy(), PERIOD_NS + k.astype(np.int64) * PERIOD_NS)
    np.testing.assert_array_equal(table["n1_rpm"].to_numpy(), 2 * k)


def warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


@pytest.mark.parametrize("fmt", FORMATS)
def test_an_all_nan_line_keeps_its_slot(tmp_path: Path, fmt: str, caplog: pytest.LogCaptureFixture) -> None:
    rows = lines(fmt)
    rows[7] = FORMATS[fmt][2]  # the logger missed sample 7
    with caplog.at_level(logging.WARNING):
        out = ingest_log(write(tmp_path / "trial01", fmt, rows), vehicle(fmt))
    assert_on_time(out, [k for k in range(N) if k != 7])
    line = 7 + 1 + (fmt == "comma")  # 1-based, after the header
    topic = out.report["topics"]["run.csv"]
    assert topic["lines"]["all_nan"] == 1 and topic["lines"]["kept"] == N - 1 and topic["lines"]["lines"] == N
    assert topic["lines_dropped"] == {"all_nan": [line]}
    assert any("run.csv" in w and f"without a value at [{line}]" in w for w in warnings(caplog))


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("where", ["inside a field", "at a delimiter"])
def test_a_split_line_takes_one_slot(tmp_path: Path, fmt: str, where: str, caplog: pytest.LogCaptureFixture) -> None:
    rows = lines(fmt)
    sep = FORMATS[fmt][0]
    cut = rows[12].index(".0") + 1 if where == "inside a field" else rows[12].rindex(sep)
    rows[12:13] = [rows[12][:cut], rows[12][cut:].lstrip(sep)]  # a stray line break in sample 12
    with caplog.at_level(logging.WARNING):
        out = ingest_log(write(tmp_path / "trial01", fmt, rows), vehicle(fmt))
    assert_on_time(out, [k for k in range(N) if k != 12])  # the split sample dropped, none after it moved
    first = 12 + 1 + (fmt == "comma")
    topic = out.report["topics"]["run.csv"]
    assert topic["lines"]["split"] == 2 and topic["lines"]["lines"] == N + 1
    assert topic["lines_dropped"] == {"split": [first, first + 1]}
    assert any("run.csv" in w and "split in two" in w and f"[{first}, {first + 1}]" in w for w in warnings(caplog))


def test_a_ragged_line_keeps_its_slot_and_a_blank_line_takes_none(tmp_path: Path) -> None:
    rows = lines("comma")
    rows[5] = rows[5].rsplit(",", 1)[0]  # a sample cut short: two fields of three
    rows[20:20] = [""]  # a stray empty line before sample 20
    rows[30] = rows[30] + ",9.0"  # one field too many
    out = ingest_log(write(tmp_path / "trial01", "comma", rows), vehicle("comma"))
    assert_on_time(out, [k for k in range(N) if k not in (5, 29)])
    topic = out.report["topics"]["run.csv"]
    assert topic["lines_dropped"] == {"ragged": [7, 32], "blank": [22]}
    assert topic["lines"]["blank"] == topic["lines"]["blank_between"] == 1 and topic["expected"] == N


def test_trailing_blank_lines_are_counted_not_warned(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    directory = write(tmp_path / "trial01", "comma", lines("comma"))
    with open(directory / "run.csv", "a") as handle:
        handle.write("\n\n")
    with caplog.at_level(logging.WARNING):
        out = ingest_log(directory, vehicle("comma"))
    assert_on_time(out, list(range(N)))
    assert out.report["topics"]["run.csv"]["lines"]["blank"] == 2
    assert out.report["topics"]["run.csv"]["lines_dropped"] == {}
    assert not [w for w in warnings(caplog) if "run.csv" in w]


def test_utf16_table_is_classified_too(tmp_path: Path) -> None:
    rows = lines("comma")
    rows[3] = ",,"
    (tmp_path / "run.csv").write_text("t,x,r\n" + "\n".join(rows) + "\n", encoding="utf-16")
    opts = CsvOptions(time_column="t", encoding="utf-16")
    data = open_text(tmp_path).read({"run.csv": ["x"]}, csv_options={"run.csv": opts}).topics["run.csv"]
    assert data.line_counts["all_nan"] == 1 and data.line_numbers == {"all_nan": [5]}
    np.testing.assert_array_equal(data.rows, [k for k in range(N) if k != 3])


def test_quoted_line_break_falls_back_to_one_row_per_record(tmp_path: Path,
                                                            caplog: pytest.LogCaptureFixture) -> None:
    (tmp_path / "q.csv").write_text('t,x,note\n0.0,1,"a\nb"\n0.1,2,c\n')
    with caplog.at_level(logging.WARNING):
        data = open_text(tmp_path).read({"q.csv": ["x"]}, csv_options={"q.csv": CsvOptions(time_column="t")})
    np.testing.assert_array_equal(data.topics["q.csv"].rows, [0, 1])
    assert any("not classified" in w for w in warnings(caplog))


@pytest.mark.parametrize(("fields", "slots", "split", "ragged"), [
    ([3, 3, 2, 2, 3], [0, 1, 2, 2, 3], [2, 3], []),   # broken inside a field: 2 + 2 = n + 1
    ([3, 2, 1, 3], [0, 1, 1, 2], [1, 2], []),         # broken at a delimiter: 2 + 1 = n
    ([3, 2, 3, 1, 3], [0, 1, 2, 3, 4], [], [1, 3]),   # short lines apart: ragged, each its own slot
    ([3, 1, 1, 3], [0, 1, 2, 3], [], [1, 2]),         # 1 + 1 < n: two short lines, not one split
    ([3, 0, 3, 2, 2, 2, 2, 3, 3], [0, -1, 1, 2, 2, 3, 3, 4, 5], [3, 4, 5, 6], []),  # two splits; blank: no slot
    ([4, 4, 4, 4], [0, 1, 2, 3], [], []),             # a trailing delimiter on every data line, not the header
])
def test_plan_lines(fields: list[int], slots: list[int], split: list[int], ragged: list[int]) -> None:
    plan = plan_lines(np.array(fields), 3)
    assert plan.slot.tolist() == slots
    assert np.flatnonzero(plan.split).tolist() == split and np.flatnonzero(plan.ragged).tolist() == ragged
