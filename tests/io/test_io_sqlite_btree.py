"""The messages table read from its pages (``pipeline.io.sqlite_btree``) gives exactly the rows sqlite gives.

The databases are written here with the standard library, rosbag2's schema, on every page size, with integers of
every serial type, payloads from empty to many overflow pages, rows deleted and rewritten (free blocks, pages that
no longer follow each other in the file): the ground truth is ``SELECT ... ORDER BY id``. What the parser does not
take (a damaged page, another schema) raises NotPlain or leaves the table to sqlite, and the reader goes on through
sqlite from the row after the last one it handed on.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.io import sqlite_btree
from pipeline.io.errors import NotPlain
from pipeline.io.rosbag2 import storage_sqlite3
from pipeline.io.sqlite_btree import row_batches

SCHEMA = ("CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, timestamp INTEGER NOT NULL, "
          "data BLOB NOT NULL)")
#: One of each integer serial type: 0 and 1 (types 8, 9), 1, 2, 3, 4, 6 and 8 bytes, negatives.
INTS = [0, 1, -1, 127, -128, 300, -40000, 8_000_000, 2**31 - 1, -(2**31), 2**40, -(2**47), 2**62, -(2**63),
        1_700_000_000_000_000_000]
LENGTHS = [0, 1, 57, 58, 200, 470, 480, 1000, 4000, 4062, 4100, 20_000, 70_000]


def write_db(path: Path, rows: list[tuple[int, int, bytes]], page_size: int, *, index: bool = True,
             churn: bool = False, ids: list[int] | None = None) -> list[tuple[int, int, int, bytes]]:
    """A rosbag2-shaped messages table (``ids``: given rowids, else 1, 2, ...); returns what sqlite reads back in
    id order."""
    con = sqlite3.connect(path)
    con.execute(f"PRAGMA page_size = {page_size}")
    con.execute(SCHEMA)
    if index:  # rosbag2 indexes the stamps: its pages lie between the table's
        con.execute("CREATE INDEX timestamp_idx ON messages (timestamp ASC)")
    if ids is None:
        con.executemany("INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)", rows)
    else:
        con.executemany("INSERT INTO messages (id, topic_id, timestamp, data) VALUES (?, ?, ?, ?)",
                        [(i, *r) for i, r in zip(ids, rows, strict=False)])
    if churn:  # free blocks on the pages, and leaves out of file order
        con.execute("DELETE FROM messages WHERE id % 3 = 0")
        con.execute("UPDATE messages SET data = CAST(data || data AS BLOB) WHERE id % 5 = 1")
        con.executemany("INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)", rows[: len(rows) // 2])
    con.commit()
    truth = list(con.execute("SELECT id, topic_id, timestamp, data FROM messages ORDER BY id"))
    con.close()
    return truth


def root_of(path: Path) -> int:
    con = sqlite3.connect(path)
    try:
        return con.execute("SELECT rootpage FROM sqlite_master WHERE name = 'messages'").fetchone()[0]
    finally:
        con.close()


def paged(path: Path, limit: int) -> list[tuple[int, int, bytes]]:
    out = []
    for b in row_batches(path, root_of(path), limit):
        out += [(t, s, b.buf[a:a + n].tobytes()) for t, s, a, n in
                zip(b.topic_id.tolist(), b.log_ns.tolist(), b.starts.tolist(), b.lengths.tolist(), strict=True)]
    return out


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(page_size=st.sampled_from([512, 1024, 4096, 65536]),
       rows=st.lists(st.tuples(st.sampled_from(INTS), st.sampled_from(INTS), st.sampled_from(LENGTHS)),
                     min_size=0, max_size=60),
       churn=st.booleans(), limit=st.sampled_from([1, 8192, 16 << 20]),
       ids=st.none() | st.lists(st.sampled_from(INTS) | st.integers(-(2**63), 2**63 - 1), unique=True))
def test_pages_give_what_sqlite_gives(tmp_path_factory: pytest.TempPathFactory, page_size: int,
                                      rows: list[tuple[int, int, int]], churn: bool, limit: int,
                                      ids: list[int] | None) -> None:
    """Rowids too (given: every varint length, negatives; else 1, 2, ...)."""
    path = tmp_path_factory.mktemp("db") / "m.db3"
    rng = np.random.default_rng(len(rows))
    data = [(t, s, rng.integers(0, 256, n, dtype=np.uint8).tobytes()) for t, s, n in rows]
    truth = write_db(path, data, page_size, churn=churn and ids is None, ids=ids)
    assert paged(path, limit) == [(t, s, d) for _, t, s, d in truth]


def test_many_rows_over_many_leaves_and_levels(tmp_path: Path) -> None:
    """Thousands of small rows on 512-byte pages: a b-tree of several interior levels, batches of a few leaves."""
    rng = np.random.default_rng(3)
    data = [(int(rng.integers(0, 9)), 1_700_000_000_000_000_000 + i, rng.bytes(int(rng.integers(0, 90))))
            for i in range(20_000)]
    path = tmp_path / "m.db3"
    truth = write_db(path, data, 512, churn=True)
    assert paged(path, 4096) == [(t, s, d) for _, t, s, d in truth]


def test_a_damaged_leaf_is_not_plain(tmp_path: Path) -> None:
    path = tmp_path / "m.db3"
    write_db(path, [(1, i, bytes(100)) for i in range(2000)], 1024, index=False)
    root = root_of(path)
    with open(path, "rb") as fh:
        layout = sqlite_btree.Layout.of(fh.fileno())
        leaves = sqlite_btree.leaf_pages(fh.fileno(), layout, root)
    raw = bytearray(path.read_bytes())
    raw[(int(leaves[len(leaves) // 2]) - 1) * 1024] = 0x02  # an index page's type where a table leaf should be
    path.write_bytes(bytes(raw))
    with pytest.raises(NotPlain, match="not a table leaf"):
        paged(path, 4096)


@pytest.mark.parametrize("bad", ["twice", "outside", "zero"])
def test_an_interior_page_pointing_twice_or_outside_the_file_is_not_plain(tmp_path: Path, bad: str) -> None:
    """A child page met twice (a loop, or two parents sharing a leaf), past the file's last page or page 0: the
    parser would read rows twice or garbage, so it stops before reading any leaf."""
    path = tmp_path / "m.db3"
    write_db(path, [(1, i, bytes(100)) for i in range(2000)], 1024, index=False)
    root = root_of(path)
    raw = bytearray(path.read_bytes())
    head = (root - 1) * 1024 + (100 if root == 1 else 0)
    assert raw[head] == 0x05 and int.from_bytes(raw[head + 3:head + 5], "big") >= 1  # an interior table page
    at = (root - 1) * 1024 + int.from_bytes(raw[head + 12:head + 14], "big")  # the first cell's left child
    child = {"twice": raw[head + 8:head + 12],  # the right-most child's number
             "outside": (len(raw) // 1024 + 1).to_bytes(4, "big"), "zero": bytes(4)}[bad]
    assert raw[at:at + 4] != child
    raw[at:at + 4] = child
    path.write_bytes(bytes(raw))
    with open(path, "rb") as fh, pytest.raises(NotPlain, match="outside the file, or met twice"):
        sqlite_btree.leaf_pages(fh.fileno(), sqlite_btree.Layout.of(fh.fileno()), root)


def test_the_reader_goes_on_through_sqlite_after_the_last_row_handed_on(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    """The page parser gives up at its third batch: sqlite's aggregates read the rows after the last id yielded,
    so every row comes once, in order."""
    path = tmp_path / "m.db3"
    rng = np.random.default_rng(5)
    truth = write_db(path, [(1 + i % 3, i, rng.bytes(50)) for i in range(3000)], 1024)
    real, calls = sqlite_btree._parse, []

    def give_up_third(*args: object) -> sqlite_btree.RowBatch:
        calls.append(1)
        if len(calls) == 3:
            raise NotPlain("a test says so")
        return real(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(sqlite_btree, "_parse", give_up_third)
    wanted = {1: "/a", 3: "/c"}
    con = sqlite3.connect(path)
    got = []
    with caplog.at_level("INFO"):
        for tid, stamp, buf, starts, lengths in storage_sqlite3._paged_rows(con, path, wanted, limit=8 * 1024):
            got += [(int(t), int(s), buf[a:a + n].tobytes()) for t, s, a, n in zip(tid, stamp, starts, lengths,
                                                                                     strict=True)]
    con.close()
    assert len(calls) == 3 and "a test says so; sqlite reads the rows after id" in caplog.text
    assert got == [(t, s, d) for _, t, s, d in truth if t in wanted]


@pytest.mark.parametrize("schema", [
    "CREATE TABLE messages(id INTEGER PRIMARY KEY, timestamp INTEGER NOT NULL, topic_id INTEGER NOT NULL, "
    "data BLOB NOT NULL)",
    "CREATE TABLE messages(id INTEGER NOT NULL, topic_id INTEGER NOT NULL, timestamp INTEGER NOT NULL, "
    "data BLOB NOT NULL, PRIMARY KEY (id)) WITHOUT ROWID",
])
def test_another_schema_is_left_to_sqlite(tmp_path: Path, schema: str) -> None:
    path = tmp_path / "m.db3"
    con = sqlite3.connect(path)
    con.execute(schema)
    con.executemany("INSERT INTO messages (id, topic_id, timestamp, data) VALUES (?, ?, ?, ?)",
                    [(i, 1, 10 * i, bytes([i])) for i in range(1, 30)])
    con.commit()
    assert storage_sqlite3._messages_root(con, path) is None
    got = [(int(t), int(s)) for tid, stamps, *_ in storage_sqlite3._paged_rows(con, path, {1: "/a"})
           for t, s in zip(tid, stamps, strict=True)]
    con.close()
    assert got == [(1, 10 * i) for i in range(1, 30)]


def test_a_write_ahead_log_beside_the_file_leaves_the_pages_to_sqlite(tmp_path: Path) -> None:
    """Rows committed to a -wal file are not on the pages yet: the pages are not read then."""
    path = tmp_path / "m.db3"
    writer = sqlite3.connect(path)
    writer.execute("PRAGMA journal_mode = WAL")
    writer.execute("PRAGMA wal_autocheckpoint = 0")
    writer.execute(SCHEMA)
    writer.executemany("INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)",
                       [(1, i, bytes(8)) for i in range(50)])
    writer.commit()
    assert Path(f"{path}-wal").stat().st_size > 0
    reader = sqlite3.connect(path)
    try:
        assert storage_sqlite3._messages_root(reader, path) is None
    finally:
        reader.close()
        writer.close()
    reader = sqlite3.connect(path)  # closing the last connection checkpointed the log into the file
    try:
        assert not Path(f"{path}-wal").exists() and storage_sqlite3._messages_root(reader, path) == root_of(path)
    finally:
        reader.close()
