"""A CSV whose configured encoding cannot read it is a clear error naming the file (issue 36, item 3); times
rebuilt from the row index never wrap round int64."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.config.sources import CsvOptions
from pipeline.errors import IngestError
from pipeline.io.text import open_text
from pipeline.stamps import uniform_times


def test_utf16_without_a_byte_order_mark_names_the_file_and_the_remedy(tmp_path: Path) -> None:
    (tmp_path / "a.csv").write_bytes("t,x\n1.0,2\n2.0,3\n".encode("utf-16-le"))  # no BOM
    with open_text(tmp_path) as reader, pytest.raises(IngestError) as info:
        reader.read({"a.csv": ["x"]}, {"a.csv": CsvOptions(time_column="t", encoding="utf-16")})
    assert str(tmp_path / "a.csv") in str(info.value) and "utf-16-le" in str(info.value)
    with open_text(tmp_path) as reader:  # the remedy the message gives reads it
        data = reader.read({"a.csv": ["x"]}, {"a.csv": CsvOptions(time_column="t", encoding="utf-16-le")})
    np.testing.assert_array_equal(data.topics["a.csv"].columns["x"], [2.0, 3.0])


def test_row_times_beyond_int64_are_an_error_not_a_wrap() -> None:
    with pytest.raises(ValueError, match="beyond int64"):
        uniform_times(1_700_000_000 * 10**9, np.arange(10_000_000), 1e-3)  # 1e10 s after 2023: past 2262
    ok = uniform_times(1_700_000_000 * 10**9, np.arange(100), 1e-3)
    assert ok[-1] == 1_700_000_000 * 10**9 + 99 * 10**12
