"""ROS 2 sqlite3 bags: the three fetches (the messages table's pages parsed by ``sqlite_btree``, batches of rows
aggregated by sqlite, and rows fetched one by one through the sqlite3 module) agree bit for bit, in batches of any
size; what the page parser does not take, sqlite reads from the next row on; a damaged row is an IngestError in
every fetch; counts that metadata.yaml states are checked against the rows read, and a wrong one is replaced by
the storage's own count."""

from __future__ import annotations

import logging
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.errors import IngestError
from pipeline.io import open_log
from pipeline.io.rosbag2.reader import Rosbag2Reader
from tests.io.helpers import REQUESTS, expected, trial, write_rosbag2


@pytest.fixture(scope="module")
def msgs() -> list:
    return trial(n=40, seed=11)


def _read(path: Path, *, rows: bool, fast: bool, pages: bool = False) -> dict:
    with open_log(path) as reader:
        assert isinstance(reader, Rosbag2Reader)
        reader._row_fetch = rows  # noqa: SLF001
        reader._page_fetch = pages  # noqa: SLF001
        reader.allow_fast = fast
        return reader.read(REQUESTS).topics


def _assert_same(a: dict, b: dict) -> None:
    assert set(a) == set(b)
    for topic, x in a.items():
        y = b[topic]
        assert x.read == y.read == x.expected
        assert x.log_ns.tobytes() == y.log_ns.tobytes() and x.header_ns.tobytes() == y.header_ns.tobytes()
        assert x.columns.keys() == y.columns.keys()
        for field in x.columns:
            assert x.columns[field].tobytes() == y.columns[field].tobytes(), (topic, field)


@pytest.mark.parametrize("fast", [True, False], ids=["fast", "per-message"])
def test_page_aggregated_and_row_fetches_give_identical_columns(tmp_path: Path, msgs: list, fast: bool) -> None:
    path = write_rosbag2(tmp_path / "bag", msgs)
    aggregated, plain = _read(path, rows=False, fast=fast), _read(path, rows=True, fast=fast)
    paged = _read(path, rows=False, fast=fast, pages=True)
    want = expected(msgs)
    assert set(aggregated) == set(REQUESTS)
    for topic, cols in want.items():
        np.testing.assert_array_equal(aggregated[topic].log_ns, cols["log_ns"])
    _assert_same(aggregated, plain)
    _assert_same(paged, plain)


@pytest.mark.parametrize("first,most", [(1, 1), (7, 16), (5, 64)])
def test_aggregated_batches_of_any_size_give_the_same_columns(tmp_path: Path, msgs: list, first: int, most: int,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """Batches follow each other by id (``id > last``); each is sized from the one before (a few rows here)."""
    import pipeline.io.rosbag2.storage_sqlite3 as storage_sqlite3

    path = write_rosbag2(tmp_path / "bag", msgs)
    plain = _read(path, rows=True, fast=True)
    monkeypatch.setattr(storage_sqlite3, "FIRST_BATCH_ROWS", first)
    monkeypatch.setattr(storage_sqlite3, "BATCH_ROWS", most)
    monkeypatch.setattr(storage_sqlite3, "BATCH_BYTES", 2000)
    _assert_same(_read(path, rows=False, fast=True), plain)


def test_empty_payloads_and_other_topics(msgs: list) -> None:
    """A zero-length payload adds nothing to the joined blob but keeps its row; rows of unwanted topics stay out."""
    from pipeline.io.rosbag2.storage_sqlite3 import _concatenated_rows, _fetched_rows

    con = sqlite3.connect(":memory:")
    con.execute("CREATE TABLE messages (id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, "
                "timestamp INTEGER NOT NULL, data BLOB NOT NULL)")
    rows = [(i, 1 + i % 3, 1_700_000_000_000_000_000 + i, bytes(range(i % 5))) for i in range(1, 40)]
    con.executemany("INSERT INTO messages VALUES (?, ?, ?, ?)", rows)
    wanted = {1: "/a", 2: "/b"}
    kept = [r for r in rows if r[1] in wanted]

    def flat(batches: object) -> list[tuple[int, int, bytes]]:
        out = []
        for tid, stamps, buf, starts, lengths in batches:  # type: ignore[attr-defined]
            out += [(int(t), int(s), buf[a:a + n].tobytes()) for t, s, a, n in zip(tid, stamps, starts, lengths,
                                                                                     strict=True)]
        return out

    assert flat(_concatenated_rows(con, wanted)) == [(t, s, d) for _, t, s, d in kept]
    assert flat(_fetched_rows(con, wanted, lambda d: d)) == [(t, s, d) for _, t, s, d in kept]


@pytest.mark.parametrize(("column", "value", "rows"), [
    ("timestamp", "'soon'", False), ("timestamp", "'soon'", True), ("timestamp", "1.5", False),
    ("data", "'text'", False), ("data", "'text'", True), ("data", "42", False), ("data", "42", True)])
@pytest.mark.parametrize("pages", [True, False], ids=["pages", "sqlite"])
def test_a_damaged_row_is_an_ingest_error(tmp_path: Path, msgs: list, column: str, value: str, rows: bool,
                                          pages: bool) -> None:
    """(Fetched one by one, a float stamp is truncated by numpy unseen; aggregated, every type is checked; the page
    parser leaves such a row to sqlite's aggregates.)"""
    path = write_rosbag2(tmp_path / "bag", msgs)
    db = next(path.glob("*.db3"))
    with sqlite3.connect(db) as con:
        con.execute(f"UPDATE messages SET {column} = {value} WHERE id = 5")
    con.close()
    with open_log(path) as reader:
        reader._row_fetch = rows  # noqa: SLF001
        reader._page_fetch = pages  # noqa: SLF001
        with pytest.raises(IngestError, match="damaged row in table 'messages'") as info:
            reader.read(REQUESTS)
    assert info.value.file == str(db)


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


@pytest.mark.parametrize(("rows", "pages"), [(False, True), (False, False), (True, False)],
                         ids=["pages", "aggregated", "rows"])
def test_directory_names_with_uri_characters_open_the_right_file_read_only(tmp_path: Path, msgs: list,
                                                                         rows: bool, pages: bool) -> None:
    """'?', '#' and '%' in a bag's path are percent-encoded in the sqlite URI: unquoted they would end the file
    name early and open, or create, another file beside the raw log."""
    write_rosbag2(tmp_path / "plain" / "bag", msgs)  # (rosbags' own writer does not quote such paths)
    parent = (tmp_path / "plain").rename(tmp_path / "sea trial #3?50%")
    path = parent / "bag"
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    topics = _read(path, rows=rows, fast=True, pages=pages)
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before
    want = expected(msgs)
    for topic, cols in want.items():
        np.testing.assert_array_equal(topics[topic].log_ns, cols["log_ns"])
