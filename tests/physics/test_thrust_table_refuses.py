"""Thrust tables that would hang or give nonsense are refused naming the file (issue 36, item 3)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from pipeline import physics
from pipeline.errors import ConfigError


def _load(path: Path | str) -> tuple[np.ndarray, np.ndarray]:
    physics._load_table.cache_clear()
    return physics._load_table(str(path), "rpm", "thrust", "N")


@pytest.mark.parametrize(("text", "says"), [
    pytest.param("rpm,thrust\n0,0\n1000,2\n1500,1\n2000,8\n", "not monotonic", id="mistyped-row"),
    pytest.param("rpm,thrust\n0,0\n1000,nan\n2000,8\n", "data row 2, column 'thrust'", id="nan"),
    pytest.param("rpm,thrust\n0,0\n1000,\n2000,8\n", "data row 2", id="empty-cell"),
    pytest.param("rpm,thrust\n0,0\ninf,2\n2000,8\n", "column 'rpm'", id="inf"),
])
def test_a_table_with_nonsense_rows_is_refused(tmp_path: Path, text: str, says: str) -> None:
    (tmp_path / "t.csv").write_text(text)
    with pytest.raises(ConfigError) as info:
        _load(tmp_path / "t.csv")
    assert says in str(info.value) and str(tmp_path / "t.csv") in str(info.value)


def test_noise_in_a_dead_band_and_wholly_empty_rows_are_fine(tmp_path: Path) -> None:
    (tmp_path / "t.csv").write_text("rpm,thrust\n-1000,-2\n0,0.01\n100,0.0\n,\n1000,2\n")
    x, thrust = _load(tmp_path / "t.csv")
    np.testing.assert_array_equal(x, [-1000, 0, 100, 1000])


@pytest.mark.parametrize("special", ["/dev/zero", "fifo", "dir"])
def test_a_table_that_is_no_regular_file_is_refused_without_reading(tmp_path: Path, special: str) -> None:
    path = Path(special)
    if special == "fifo":
        path = tmp_path / "table.csv"
        os.mkfifo(path)  # opening it would block until a writer comes
    elif special == "dir":
        path = tmp_path
    with pytest.raises(ConfigError, match="not a regular file"):
        _load(path)


def test_a_table_larger_than_the_cap_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(physics, "MAX_TABLE_BYTES", 64)
    (tmp_path / "t.csv").write_text("rpm,thrust\n" + "".join(f"{i},{i}\n" for i in range(20)))
    with pytest.raises(ConfigError, match="larger than"):
        _load(tmp_path / "t.csv")
