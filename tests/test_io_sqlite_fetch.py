"""ROS 2 sqlite3 bags: the Arrow (ADBC) and sqlite3-module fetch paths agree bit for bit; counts that metadata.yaml
states are checked against the rows read, and a wrong one is replaced by the storage's own count."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
import yaml
from io_helpers import REQUESTS, expected, trial, write_rosbag2

from pipeline.io import open_log
from pipeline.io.rosbag2 import Rosbag2Reader


@pytest.fixture(scope="module")
def msgs() -> list:
    return trial(n=40, seed=11)


def _read(path: Path, *, adbc: bool, fast: bool) -> dict:
    with open_log(path) as reader:
        assert isinstance(reader, Rosbag2Reader)
        reader._no_adbc = not adbc  # noqa: SLF001
        reader.allow_fast = fast
        topics = reader.read(REQUESTS).topics
        assert reader._no_adbc is not adbc  # noqa: SLF001 - the Arrow path did not fall back
        return topics


@pytest.mark.parametrize("fast", [True, False], ids=["fast", "per-message"])
def test_arrow_and_sqlite3_module_give_identical_columns(tmp_path: Path, msgs: list, fast: bool) -> None:
    pytest.importorskip("adbc_driver_sqlite")
    path = write_rosbag2(tmp_path / "bag", msgs)
    arrow, plain = _read(path, adbc=True, fast=fast), _read(path, adbc=False, fast=fast)
    want = expected(msgs)
    assert set(arrow) == set(plain) == set(REQUESTS)
    for topic, a in arrow.items():
        b = plain[topic]
        assert a.read == b.read == len(want[topic]["log_ns"])
        assert a.log_ns.tobytes() == b.log_ns.tobytes() and a.header_ns.tobytes() == b.header_ns.tobytes()
        np.testing.assert_array_equal(a.log_ns, want[topic]["log_ns"])
        assert a.columns.keys() == b.columns.keys()
        for field in a.columns:
            assert a.columns[field].tobytes() == b.columns[field].tobytes(), (topic, field)


def test_listed_counts_are_checked_by_the_read(tmp_path: Path, msgs: list, caplog: pytest.LogCaptureFixture) -> None:
    path = write_rosbag2(tmp_path / "bag", msgs)
    want = expected(msgs)
    meta_path = path / "metadata.yaml"
    doc = yaml.safe_load(meta_path.read_text())
    for entry in doc["rosbag2_bagfile_information"]["topics_with_message_count"]:
        if entry["topic_metadata"]["name"] == "/dvl/data":
            entry["message_count"] += 5  # the recorder's summary is wrong
    meta_path.write_text(yaml.safe_dump(doc))
    with open_log(path) as reader:
        listed = reader.catalog()
        assert listed["/dvl/data"].count == len(want["/dvl/data"]["log_ns"]) + 5
        assert listed["/dvl/data"].first_ns is None
        with caplog.at_level(logging.WARNING):
            topics = reader.read(REQUESTS).topics
        assert "metadata.yaml says topic /dvl/data" in caplog.text
        n = len(want["/dvl/data"]["log_ns"])
        assert topics["/dvl/data"].read == topics["/dvl/data"].expected == n
        after = reader.catalog()
        assert after["/dvl/data"].count == n and after["/dvl/data"].first_ns == want["/dvl/data"]["log_ns"][0]
        assert {t: i.count for t, i in reader.topics().items()} == {t: len(c["log_ns"]) for t, c in want.items()}


def test_catalog_fills_time_ranges_from_the_read(tmp_path: Path, msgs: list) -> None:
    path = write_rosbag2(tmp_path / "bag", msgs)
    want = expected(msgs)
    with open_log(path) as reader:
        assert all(i.first_ns is None for i in reader.catalog().values())
        reader.read(REQUESTS)
        infos = reader.catalog()
    for topic, cols in want.items():
        assert infos[topic].count == len(cols["log_ns"])
        assert (infos[topic].first_ns, infos[topic].last_ns) == (cols["log_ns"].min(), cols["log_ns"].max())
