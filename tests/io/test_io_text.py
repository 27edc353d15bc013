"""The CSV reader: every layout a lab exports gives the same stamps and values, exactly."""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline.config.sources import CsvOptions
from pipeline.errors import IngestError
from pipeline.io.text import is_gzip, open_text, sniff_delimiter
from tests.fixturepaths import SHARED, T200_CSV, shared_fixture

T200 = SHARED / "csv" / "bluerobotics_t200_performance_10-20V.csv"

N = 25
BASE_NS = 1_700_000_000_000_000_000
T_NS = BASE_NS + np.arange(N, dtype=np.int64) * 10_000_007  # 10 ms + 7 ns: float64 seconds would lose the 7 ns
RATE = np.round(np.sin(np.arange(N) / 3.0) * 30.0, 6)
N1 = np.round(np.arange(N) * 1.25 - 7.0, 6)
UNIT_NS = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "µs": 1_000, "ns": 1}


def stamp_text(t_ns: int, unit: str) -> str:
    scale = UNIT_NS[unit]
    if scale == 1:
        return str(t_ns)
    whole, frac = divmod(t_ns, scale)
    return f"{whole}.{frac:0{len(str(scale)) - 1}d}"


def write_csv(path: Path, *, sep: str = ",", unit: str = "s", relative: bool = False, header: bool = True,
              preamble: int = 0, time_name: str = "t", padded_header: bool = False, gz: bool = False) -> CsvOptions:
    lines = [f"# preamble line {i}: exported by LabTool 3.1" for i in range(preamble)]
    if header:
        names = [time_name, "rate", "n1"]
        if padded_header:
            names = [f" {n} " for n in names]
        lines.append(sep.join(names))
    epoch = BASE_NS // 1_000_000_000 if relative else 0
    for i in range(N):
        t = int(T_NS[i]) - epoch * 1_000_000_000
        lines.append(sep.join([stamp_text(t, unit), repr(float(RATE[i])), repr(float(N1[i]))]))
    text = "\n".join(lines) + "\n"
    if gz:
        path.write_bytes(gzip.compress(text.encode("utf-8"), mtime=0))
    else:
        path.write_text(text, encoding="utf-8")
    return CsvOptions(time_column=time_name, time_unit=unit, time_origin="relative" if relative else "absolute",
                      epoch_s=float(epoch), skip_rows=preamble, header=header,
                      columns=None if header else [time_name, "rate", "n1"])


VARIANTS = {
    "comma": {},
    "tab": {"sep": "\t"},
    "semicolon": {"sep": ";"},
    "whitespace": {"sep": "   "},
    "preamble": {"preamble": 3},
    "headerless": {"header": False},
    "micro_sign_padded_header": {"time_name": "t (µs)", "unit": "µs", "padded_header": True},
    "gzip": {"gz": True},
    "ms_absolute": {"unit": "ms"},
    "us_absolute": {"unit": "us"},
    "ns_absolute": {"unit": "ns"},
    "s_relative": {"relative": True},
    "ms_relative": {"unit": "ms", "relative": True},
    "ns_relative_tab_gzip_preamble": {"unit": "ns", "relative": True, "sep": "\t", "gz": True, "preamble": 2},
}


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_variants_give_identical_stamps_and_values(tmp_path: Path, variant: str) -> None:
    name = "fog.csv.gz" if VARIANTS[variant].get("gz") else "fog.csv"
    opts = write_csv(tmp_path / name, **VARIANTS[variant])  # type: ignore[arg-type]
    with open_text(tmp_path) as reader:
        assert list(reader.topics()) == [name]
        result = reader.read({name: ["rate", "n1"]}, csv_options={name: opts})
        assert reader.topics()[name].count == N
    data = result.topics[name]
    np.testing.assert_array_equal(data.log_ns, T_NS)
    assert data.log_ns.dtype == np.int64
    np.testing.assert_array_equal(data.columns["rate"], RATE)
    np.testing.assert_array_equal(data.columns["n1"], N1)
    assert data.read == data.expected == N
    assert data.header_ns is None and data.msgtype == "csv"


def test_gzip_detected_by_content_not_name(tmp_path: Path) -> None:
    opts = write_csv(tmp_path / "plain_name.csv", gz=True)
    assert is_gzip(tmp_path / "plain_name.csv")
    with open_text(tmp_path) as reader:
        data = reader.read({"plain_name.csv": ["rate"]}, csv_options={"plain_name.csv": opts}).topics["plain_name.csv"]
    np.testing.assert_array_equal(data.log_ns, T_NS)


def test_sniff_delimiter() -> None:
    assert sniff_delimiter(["a,b,c", "1,2,3"]) == ","
    assert sniff_delimiter(["a\tb", "1\t2"]) == "\t"
    assert sniff_delimiter(["a;b", "1,5;2,5"]) == ";"
    assert sniff_delimiter(["a  b   c", " 1 2 3"]) == r"\s+"


def test_t200_fixture_reads_with_right_columns_and_values(tmp_path: Path) -> None:
    trial = tmp_path / "t200"
    trial.mkdir()
    shutil.copy(shared_fixture(T200_CSV), trial / T200.name)
    with open_text(trial) as reader:
        columns = reader.fields(T200.name)
        assert columns == ["PWM (µs)", "RPM", "Current (A)", "Voltage (V)", "Power (W)", "Force (Kg f)",
                           "Efficiency (g/W)"]
        opts = CsvOptions(time_column="PWM (µs)", time_unit="µs", time_origin="relative")
        data = reader.read({T200.name: ["RPM", "Force (Kg f)", " Current (A) "]},
                           csv_options={T200.name: opts}).topics[T200.name]
    assert data.read == data.expected == 201
    assert data.log_ns[0] == 1_100_000 and data.log_ns[1] == 1_104_000
    assert data.columns["RPM"][0] == 3465.0
    assert data.columns["Force (Kg f)"][0] == -4.07
    assert data.columns["Current (A)"][0] == 24.30


def test_unparseable_value_drops_row_and_reports_line(tmp_path: Path) -> None:
    path = tmp_path / "d.csv"
    path.write_text("# preamble\nt,a,b\n1.0,1,2\n2.0,oops,3\n\n3.0,4,5\n4.0,,6\n")
    opts = CsvOptions(time_column="t", skip_rows=1)
    data = open_text(tmp_path).read({"d.csv": ["a", "b"]}, csv_options={"d.csv": opts}).topics["d.csv"]
    assert data.dropped_lines == [4] and data.dropped_count == 1
    np.testing.assert_array_equal(data.log_ns, [1_000_000_000, 3_000_000_000, 4_000_000_000])
    np.testing.assert_array_equal(data.columns["b"], [2.0, 5.0, 6.0])
    assert np.isnan(data.columns["a"][2])  # empty cell: missing value kept, not a dropped row
    assert data.expected == 4 and data.read == 3


def test_bad_time_stamp_raises_with_line(tmp_path: Path) -> None:
    (tmp_path / "d.csv").write_text("t,a\n1.0,1\nnoon,2\n3.0,3\n")
    with pytest.raises(IngestError, match=r"line\(s\) \[3\]") as info:
        open_text(tmp_path).read({"d.csv": ["a"]}, csv_options={"d.csv": CsvOptions(time_column="t")})
    assert info.value.field == "t" and info.value.topic == "d.csv"


def test_exponent_time_stamps_parse(tmp_path: Path) -> None:
    (tmp_path / "d.csv").write_text("t,a\n1.5e0,1\n2e0,2\n")
    data = open_text(tmp_path).read({"d.csv": ["a"]}, csv_options={"d.csv": CsvOptions(time_column="t")})
    np.testing.assert_array_equal(data.topics["d.csv"].log_ns, [1_500_000_000, 2_000_000_000])


@pytest.mark.parametrize(
    ("content", "match"),
    [(b"", "empty"), (b"\n\n", "empty"), (b"\x00\xff\xfe garbage \x81\x82", "cannot")],
)
def test_empty_and_garbage_files_raise_ingest_error_naming_file(tmp_path: Path, content: bytes, match: str) -> None:
    (tmp_path / "bad.csv").write_bytes(content)
    with pytest.raises(IngestError, match=match) as info:
        open_text(tmp_path).read({"bad.csv": ["a"]}, csv_options={"bad.csv": CsvOptions(time_column="t")})
    assert "bad.csv" in str(info.value)


def test_missing_column_and_file_name_what_is_available(tmp_path: Path) -> None:
    opts = write_csv(tmp_path / "fog.csv")
    reader = open_text(tmp_path)
    with pytest.raises(IngestError, match=r"no column 'yaw'.*available: \['t', 'rate', 'n1'\]") as info:
        reader.read({"fog.csv": ["yaw"]}, csv_options={"fog.csv": opts})
    assert info.value.field == "yaw"
    with pytest.raises(IngestError, match=r"no file 'dvl.csv'.*\['fog.csv'\]"):
        reader.read({"dvl.csv": ["x"]})


def test_directory_without_text_files_is_an_ingest_error(tmp_path: Path) -> None:
    (tmp_path / "notes.bin").write_bytes(b"\x00")
    with pytest.raises(IngestError, match="no delimited text files"):
        open_text(tmp_path)
