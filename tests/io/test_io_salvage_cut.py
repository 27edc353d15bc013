"""A sqlite3 .db3 and a gzip CSV cut short keep every row / line that lies wholly before the cut (issue 17, item 3).

The logs are written by the libraries' own writers (rosbags for the bag, ``zlib`` / ``gzip`` for the CSV); which
rows lie before a cut is found independently of the reader: a message row's payload is the last column of its
sqlite record, so the row lies wholly before the cut when its payload bytes do (found verbatim in the file); a
CSV line lies before the cut when the sync-flush point written after it does.
"""

from __future__ import annotations

import gzip
import io
import zlib
from pathlib import Path

import numpy as np
import pytest

from pipeline.config.sources import CsvOptions
from pipeline.errors import IngestError
from pipeline.io import open_log
from pipeline.io.text import inflate_cut, open_text
from tests.io.helpers import REQUESTS, build, expected, ros2_store, trial, write_rosbag2

CUTS = 20


def _cuts(size: int, lo: int) -> list[int]:
    return sorted({int(c) for c in np.linspace(lo, size - 1, CUTS)})


# -- gzip CSV ------------------------------------------------------------------------------------------------
def _lines(n: int) -> list[bytes]:
    return [b"t,u,v\n"] + [f"{1700000000 + i / 10:.1f},{i * 0.5},{-i}\n".encode() for i in range(n)]


def _gzip_with_flush_points(lines: list[bytes]) -> tuple[bytes, list[int]]:
    """A gzip file with a sync flush after every line: (the file, the compressed offset after each line)."""
    comp = zlib.compressobj(6, zlib.DEFLATED, 31)
    out, ends = bytearray(), []
    for line in lines:
        out += comp.compress(line)
        out += comp.flush(zlib.Z_SYNC_FLUSH)
        ends.append(len(out))
    out += comp.flush()
    return bytes(out), ends


def _read_csv(trial_dir: Path):  # noqa: ANN202
    with open_text(trial_dir) as reader:
        return reader.read({"dvl.csv.gz": ["u", "v"]}, csv_options={"dvl.csv.gz": CsvOptions(time_column="t")})


def test_cut_gzip_csv_keeps_every_line_before_the_cut(tmp_path: Path) -> None:
    lines = _lines(400)
    data, ends = _gzip_with_flush_points(lines)
    trial_dir = tmp_path / "trial"
    trial_dir.mkdir()
    path = trial_dir / "dvl.csv.gz"
    for cut in _cuts(len(data), ends[0]):
        path.write_bytes(data[:cut])
        before = sum(end <= cut for end in ends)  # lines (header included) wholly before the cut
        text, info = inflate_cut(path)
        kept = text.count(b"\n")
        assert before <= kept <= before + 1, cut  # +1: a line whose data, not its flush marker, is before the cut
        assert text == b"".join(lines[:kept])
        assert info.stopped_at_byte == cut and info.kept == kept
        result = _read_csv(trial_dir)  # before: EOFError -> IngestError, nothing kept
        got = result.topics["dvl.csv.gz"]
        rows = kept - 1
        assert got.read == rows
        np.testing.assert_array_equal(got.columns["v"], -np.arange(rows, dtype=np.float64))
        np.testing.assert_array_equal(got.log_ns, 1_700_000_000_000_000_000 + np.arange(rows) * 100_000_000)
        assert result.salvage is not None and result.salvage.kept == rows
        assert "cut short" in result.salvage.reason and "dvl.csv.gz" in result.salvage.reason


def test_cut_gzip_csv_as_gzip_writes_it(tmp_path: Path) -> None:
    """A plain ``gzip`` file (no flush points) keeps what Python's gzip module can read before its EOFError."""
    lines = _lines(3000)
    data = gzip.compress(b"".join(lines), mtime=0)
    trial_dir = tmp_path / "trial"
    trial_dir.mkdir()
    path = trial_dir / "dvl.csv.gz"
    for cut in _cuts(len(data), 20):
        path.write_bytes(data[:cut])
        readable = bytearray()
        with gzip.GzipFile(fileobj=io.BytesIO(data[:cut])) as fh:
            try:
                while piece := fh.read1(1 << 16):
                    readable += piece
            except EOFError:
                pass
        complete = bytes(readable[:readable.rfind(b"\n") + 1])
        text, _ = inflate_cut(path)
        assert text == complete, cut
        if complete.count(b"\n") > 1:
            assert _read_csv(trial_dir).topics["dvl.csv.gz"].read == complete.count(b"\n") - 1


def test_gzip_csv_in_two_members_cut_in_the_second(tmp_path: Path) -> None:
    lines = _lines(200)
    first, second = gzip.compress(b"".join(lines[:100]), mtime=0), gzip.compress(b"".join(lines[100:]), mtime=0)
    path = tmp_path / "dvl.csv.gz"
    path.write_bytes(first + second[:len(second) // 2])
    text, info = inflate_cut(path)
    assert text == b"".join(lines[:text.count(b"\n")]) and text.count(b"\n") > 100
    assert info.stopped_at_byte == len(first) + len(second) // 2


def test_gzip_corrupt_not_cut_is_an_error(tmp_path: Path) -> None:
    data = bytearray(gzip.compress(b"".join(_lines(300)), mtime=0))
    data[-6] ^= 0xFF  # the CRC-32 of the trailer: every byte is there, some are wrong
    path = tmp_path / "dvl.csv.gz"
    path.write_bytes(bytes(data))
    with pytest.raises(IngestError, match="does not decompress"):
        inflate_cut(path)


# -- sqlite3 .db3 --------------------------------------------------------------------------------------------
DB_MSGS = trial(n=150, seed=11)


def _payload_spans(data: bytes) -> list[tuple[int, int]]:
    """(offset, end) of each message's serialized payload in the file, found verbatim (each exactly once)."""
    store = ros2_store()
    spans = []
    for m in DB_MSGS:
        raw = bytes(store.serialize_cdr(build(store, m, ros1=False), m.msgtype))
        at = data.find(raw)
        assert at > 0 and data.find(raw, at + 1) < 0
        spans.append((at, at + len(raw)))
    return spans


def _check_rows(result, kept: list) -> None:  # noqa: ANN001
    want = expected(kept)
    for topic, data in result.topics.items():
        w = want.get(topic, {"log_ns": np.zeros(0, np.int64)})
        np.testing.assert_array_equal(data.log_ns, w["log_ns"])
        for field, col in data.columns.items():
            np.testing.assert_array_equal(col, w.get(field, np.zeros(0)))


@pytest.mark.parametrize("metadata", [True, False])
def test_cut_db3_keeps_every_row_before_the_cut(tmp_path: Path, metadata: bool) -> None:
    bag = write_rosbag2(tmp_path / "bag", DB_MSGS)
    db = next(bag.glob("*.db3"))
    if not metadata:  # a bare storage file: no count to compare with
        (bag / "metadata.yaml").unlink()
    data = db.read_bytes()
    spans = _payload_spans(data)
    for cut in _cuts(len(data), min(start for start, _ in spans)):
        db.write_bytes(data[:cut])
        kept = [m for m, (_, end) in zip(DB_MSGS, spans, strict=True) if end <= cut]
        with open_log(bag) as reader:  # before: IngestError 'database disk image is malformed', nothing kept
            result = reader.read({t: f for t, f in REQUESTS.items() if t in reader.topics()})
        assert result.salvage is not None, cut
        assert sum(d.read for d in result.topics.values()) == len(kept), cut
        _check_rows(result, kept)
        assert result.salvage.kept == len(kept)
        assert "cut short" in result.salvage.reason and db.name in result.salvage.reason


def _blob_db(path: Path, n: int = 60) -> list[bytes]:
    """A messages table as rosbag2 declares it, written by sqlite; blobs of 10 B .. 9 KB (overflow pages)."""
    import sqlite3

    rng = np.random.default_rng(5)
    blobs = [rng.bytes(int(s)) for s in rng.integers(10, 9000, size=n)]
    con = sqlite3.connect(path)
    con.execute("CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, "
                "serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL)")
    con.execute("CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, "
                "timestamp INTEGER NOT NULL, data BLOB NOT NULL)")
    con.executemany("INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)",
                    [(1 + i % 2, 1000 + i, b) for i, b in enumerate(blobs)])
    con.commit()
    con.close()
    return blobs


def _last_byte(data: bytes, blob: bytes) -> int:
    """Offset past the last file byte of the cell holding ``blob`` and of its overflow pages (the blob is found
    as maximal verbatim pieces)."""
    end, rest = 0, blob
    while rest:
        lo, hi = 1, len(rest)
        while lo < hi:
            mid = (lo + hi + 1) // 2
            lo, hi = (mid, hi) if data.find(rest[:mid]) >= 0 else (lo, mid - 1)
        at = data.find(rest[:lo])
        assert at >= 0
        spills = rest is blob and lo < len(blob)  # the cell's own part ends with a 4-byte overflow page number
        end, rest = max(end, at + lo + 4 * spills), rest[lo:]
    return end


def test_page_rows_with_overflow_pages(tmp_path: Path) -> None:
    from pipeline.io.sqlite_pages import SqlitePages, message_payloads, message_rows

    db = tmp_path / "blobs.db3"
    blobs = _blob_db(db)
    data = db.read_bytes()
    with SqlitePages(db) as pages:  # intact: every row, as sqlite gives them
        rows = message_rows(pages, {1, 2})
        got = list(message_payloads(pages, rows, {1, 2}))
    assert got == [(1 + i % 2, 1000 + i, b) for i, b in enumerate(blobs)]
    ends = [_last_byte(data, b) for b in blobs]
    for cut in _cuts(len(data), 4096):
        db.write_bytes(data[:cut])
        with SqlitePages(db) as pages:
            rows = message_rows(pages, {1, 2})
            got = {stamp - 1000: blob for _, stamp, blob in message_payloads(pages, rows, {1, 2})}
        before = {i for i, end in enumerate(ends) if end <= cut}
        assert before <= set(got), cut  # every row wholly before the cut
        assert all(got[i] == blobs[i] for i in got)  # and nothing else, or nothing wrong
        assert set(got) == before, cut  # a row with a byte past the cut is not half-kept


def test_db3_with_bytes_inserted_is_not_called_cut(tmp_path: Path) -> None:
    from pipeline.io.sqlite_pages import cut_short

    bag = write_rosbag2(tmp_path / "bag", DB_MSGS)
    db = next(bag.glob("*.db3"))
    data = db.read_bytes()
    assert cut_short(db) is None
    db.write_bytes(data[:len(data) // 2] + bytes(100) + data[len(data) // 2:])
    assert cut_short(db) is None  # longer than its header says: damaged, not cut
    db.write_bytes(data[:-100])
    assert "ends 3996 bytes into page" in (cut_short(db) or "")
    db.write_bytes(data[:-4096])
    assert "pages of the" in (cut_short(db) or "")


def test_cut_gzip_csv_sniffs_like_it_reads(tmp_path: Path) -> None:
    from pipeline.io.csvsniff import sniff_csv

    data = gzip.compress(b"".join(_lines(200)), mtime=0)
    path = tmp_path / "dvl.csv.gz"
    path.write_bytes(data[:len(data) // 2])
    found = sniff_csv(path)  # auvid inspect / init; before: 'gzip stream does not decompress' (EOFError)
    assert found.columns == ["t", "u", "v"] and found.delimiter == ","


def test_gzip_csv_zero_padding_between_members_then_cut(tmp_path: Path) -> None:
    lines = _lines(200)
    first, second = gzip.compress(b"".join(lines[:100]), mtime=0), gzip.compress(b"".join(lines[100:]), mtime=0)
    path = tmp_path / "dvl.csv.gz"
    path.write_bytes(first + bytes(64) + second[:len(second) // 2])  # gzip reads padded members
    text, info = inflate_cut(path)
    assert text == b"".join(lines[:text.count(b"\n")]) and text.count(b"\n") > 100
