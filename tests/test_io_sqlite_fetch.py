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


def test_arrow_failure_midway_rereads_through_the_sqlite3_module(tmp_path: Path, msgs: list,
                                                                 monkeypatch: pytest.MonkeyPatch,
                                                                 caplog: pytest.LogCaptureFixture) -> None:
    """ADBC giving up after some batches were decoded (a column whose type changes between record batches):
    the read starts again through the sqlite3 module, and nothing is counted twice."""
    pytest.importorskip("adbc_driver_sqlite")
    import pipeline.io.rosbag2 as rosbag2

    path = write_rosbag2(tmp_path / "bag", msgs)
    plain = _read(path, adbc=False, fast=True)
    monkeypatch.setattr(rosbag2, "BATCH_ROWS", 16)
    real = rosbag2._arrow_columns  # noqa: SLF001
    calls = {"n": 0}

    def flaky(rb: object) -> tuple:
        calls["n"] += 1
        if calls["n"] == 2:
            raise rosbag2._ArrowUnfit("payload column of type string")  # noqa: SLF001
        return real(rb)

    monkeypatch.setattr(rosbag2, "_arrow_columns", flaky)
    with open_log(path) as reader, caplog.at_level(logging.INFO):
        topics = reader.read(REQUESTS).topics
        assert reader._no_adbc  # noqa: SLF001
    assert calls["n"] == 2
    assert "reading rows through the sqlite3 module (payload column of type string)" in caplog.text
    for topic, a in topics.items():
        b = plain[topic]
        assert a.read == b.read == a.expected
        assert a.log_ns.tobytes() == b.log_ns.tobytes()
        for field in a.columns:
            assert a.columns[field].tobytes() == b.columns[field].tobytes(), (topic, field)


def test_unreadable_by_adbc_from_the_start_falls_back_without_restart(tmp_path: Path, msgs: list,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("adbc_driver_sqlite")
    import adbc_driver_manager
    import adbc_driver_sqlite.dbapi as adbc

    path = write_rosbag2(tmp_path / "bag", msgs)
    plain = _read(path, adbc=False, fast=True)

    def refuse(*_a: object, **_k: object) -> None:
        raise adbc.OperationalError("cannot open", status_code=adbc_driver_manager.AdbcStatusCode.IO)

    monkeypatch.setattr(adbc, "connect", refuse)
    with open_log(path) as reader:
        topics = reader.read(REQUESTS).topics
        assert reader._no_adbc  # noqa: SLF001
    for topic, a in topics.items():
        assert a.read == plain[topic].read
        assert a.columns.keys() == plain[topic].columns.keys()
        for field in a.columns:
            assert a.columns[field].tobytes() == plain[topic].columns[field].tobytes(), (topic, field)


@pytest.mark.parametrize("adbc", [True, False], ids=["arrow", "sqlite3-module"])
def test_directory_names_with_uri_characters_open_the_right_file_read_only(tmp_path: Path, msgs: list,
                                                                         adbc: bool) -> None:
    """'?', '#' and '%' in a bag's path are percent-encoded in the sqlite URI: unquoted they would end the file
    name early and open, or create, another file beside the raw log."""
    if adbc:
        pytest.importorskip("adbc_driver_sqlite")
    write_rosbag2(tmp_path / "plain" / "bag", msgs)  # (rosbags' own writer does not quote such paths)
    parent = (tmp_path / "plain").rename(tmp_path / "sea trial #3?50%")
    path = parent / "bag"
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    topics = _read(path, adbc=adbc, fast=True)
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before
    want = expected(msgs)
    for topic, cols in want.items():
        np.testing.assert_array_equal(topics[topic].log_ns, cols["log_ns"])
