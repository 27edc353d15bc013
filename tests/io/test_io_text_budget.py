"""Inflated text is capped and counted without a Python loop per line (issue 36, item 4): a small ``.csv.gz`` of
gigabytes of rows is refused, naming the file and the limit, within seconds and a few MiB of memory; a cut
MCAP chunk inflates to no more than the size it claims."""

from __future__ import annotations

import gzip
import io
import time
import tracemalloc
from pathlib import Path

import pytest
import zstandard

from pipeline.errors import IngestError
from pipeline.io import textlines
from pipeline.io.inspect import inspect_log
from pipeline.io.mcap_records import decompress
from pipeline.io.text import TEXT_MAX_BYTES, TEXT_MAX_LINE_BYTES, TEXT_MAX_LINES, inflate_cut, open_text
from pipeline.io.textlines import scan_lines

_WIDE = b"0" * 122 + b",0,0\n"  # 128-byte lines: the byte budget is met before the line budget
_NARROW = b"0,0,0\n"


def _bomb(path: Path, inflated: int, row: bytes = _WIDE) -> Path:
    """A .csv.gz of gzip members (gzip allows many) that inflates to ``inflated`` bytes: a header, then rows of
    8 MiB a member (~8 kB gzipped)."""
    rows = row * ((8 << 20) // len(row))
    path.parent.mkdir(exist_ok=True)
    path.write_bytes(gzip.compress(b"t,u,v\n" + rows, compresslevel=9)
                     + gzip.compress(rows, compresslevel=9) * (inflated // len(rows)))
    return path


def _refusal(run: object) -> tuple[IngestError, float, int]:
    import pandas  # noqa: F401 - the reader imports it; its import is not what is measured

    tracemalloc.start()
    t0 = time.process_time()
    try:
        with pytest.raises(IngestError) as info:
            run()  # type: ignore[operator]
        cpu = time.process_time() - t0
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return info.value, cpu, peak


def test_a_small_csv_gz_of_gigabytes_of_rows_is_refused_fast_in_bounded_memory(tmp_path: Path) -> None:
    path = _bomb(tmp_path / "nav.csv.gz", TEXT_MAX_BYTES + (64 << 20))
    assert path.stat().st_size < 5 << 20  # the was 4.7 MB
    err, cpu, peak = _refusal(lambda: open_text(tmp_path).topics())
    assert err.file == str(path) and f"more than {TEXT_MAX_BYTES} bytes of text (inflated)" in str(err)
    assert peak < 64 << 20, f"{peak} bytes held to count the lines"
    assert cpu < 20, f"{cpu:.1f} s of CPU to refuse it"  # ~2 s alone; the shared CI cores are slower


def test_a_small_csv_gz_of_too_many_short_lines_is_refused(tmp_path: Path) -> None:
    """Ten million lines of a few bytes each stay under the byte budget; the line budget refuses them (each
    line costs the parser far more than its bytes)."""
    path = _bomb(tmp_path / "nav.csv.gz", TEXT_MAX_LINES * len(_NARROW) + (8 << 20), row=_NARROW)
    err, cpu, peak = _refusal(lambda: open_text(path).read({"nav.csv.gz": ["u"]}))
    assert err.file == str(path) and f"more than {TEXT_MAX_LINES} lines" in str(err)
    assert peak < 64 << 20 and cpu < 20


def test_read_and_inspect_refuse_before_parsing(tmp_path: Path) -> None:
    """read() checks the budget before pandas sees the file; `auvid inspect` says the same."""
    path = tmp_path / "nav.csv"
    path.write_bytes(b"t,u,v\n" + b"".join(b"%d,1,2\n" % i for i in range(2000)))
    reader = open_text(path, max_lines=1000)
    with pytest.raises(IngestError, match="more than 1000 lines, the limit per text file") as info:
        reader.read({"nav.csv": ["u"]})
    assert info.value.file == str(path)
    small = open_text(path)
    assert small.read({"nav.csv": ["u"]}).topics["nav.csv"].read == 2000  # the default budget reads it
    bomb = _bomb(tmp_path / "dir" / "imu.csv.gz", TEXT_MAX_BYTES + (64 << 20))
    with pytest.raises(IngestError, match="limit per text file") as info:
        inspect_log(bomb.parent)
    assert info.value.file == str(bomb)


def test_a_cut_gzip_bomb_is_refused_without_inflating_it_whole(tmp_path: Path) -> None:
    """A .gz cut short is salvaged in memory (its complete lines); the budget caps that too."""
    path = _bomb(tmp_path / "nav.csv.gz", 256 << 20)
    path.write_bytes(path.read_bytes()[:-100])  # cut inside the last member
    reader = open_text(path, max_bytes=64 << 20)
    err, _cpu, peak = _refusal(lambda: reader.read({"nav.csv.gz": ["u"]}))
    assert "more than 67108864 bytes" in str(err) and err.file == str(path)
    assert peak < 100 << 20, f"{peak} bytes inflated for a 64 MiB budget"
    err, _cpu, peak = _refusal(lambda: inflate_cut(path, 64 << 20))  # the salvage itself, should it come first
    assert "inflates to more than 67108864 bytes" in str(err) and err.file == str(path)
    assert peak < 100 << 20, f"{peak} bytes inflated for a 64 MiB budget"


@pytest.mark.parametrize("block", [1, 3, 7, 1 << 22])
@pytest.mark.parametrize("head", [0, 2, 1 << 16])
def test_lines_are_counted_as_the_reader_counts_them(monkeypatch: pytest.MonkeyPatch, block: int, head: int) -> None:
    """Blank and white-space-only lines are not data; the last line needs no line end; the first ``skip`` lines
    are preamble and header, whatever they hold; block boundaries anywhere (one byte, mid-line)."""
    monkeypatch.setattr(textlines, "_BLOCK", block)
    monkeypatch.setattr(textlines, "_HEAD_BLOCK", block)
    monkeypatch.setattr(textlines, "_HEAD", head)
    text = b"# preamble\n\nt,u\n1,2\n\n \t\r\n3,4\r\n\n\n5,6\n  7,8"
    for skip, data in ((0, 6), (1, 5), (2, 5), (3, 4), (4, 3), (12, 0)):
        scan = scan_lines(io.BytesIO(text), skip=skip, max_bytes=1 << 20, max_lines=1 << 20)
        assert (scan.lines, scan.data_lines, scan.any_content, scan.over) == (11, data, True, None), skip
        whole = scan_lines(io.BytesIO(text), skip=0, max_bytes=1 << 20, max_lines=1 << 20)
        assert whole.data_after(skip) in (data, None)
    blank = scan_lines(io.BytesIO(b" \n\n\t"), skip=0, max_bytes=10, max_lines=10)
    assert (blank.lines, blank.data_lines, blank.any_content) == (3, 0, False)
    assert scan_lines(io.BytesIO(text), skip=0, max_bytes=20, max_lines=99).over == "bytes"
    assert scan_lines(io.BytesIO(text), skip=0, max_bytes=99, max_lines=10).over == "lines"


def test_a_line_longer_than_the_limit_is_refused_before_pandas_buffers_it(tmp_path: Path) -> None:
    """One 40-MiB line (no line end) in a 40-kB .gz: pandas would buffer it whole to read the header."""
    path = tmp_path / "nav.csv.gz"
    path.write_bytes(gzip.compress(b"t,u" + b",0" * (20 << 20), compresslevel=9))
    err, _cpu, peak = _refusal(lambda: open_text(path).read({"nav.csv.gz": ["u"]}))
    assert f"a line longer than {TEXT_MAX_LINE_BYTES} bytes" in str(err) and err.file == str(path)
    assert "line 1)" in str(err) and peak < 64 << 20


@pytest.mark.parametrize("block", [1, 7, 64])
def test_the_longest_line_is_found_across_blocks(monkeypatch: pytest.MonkeyPatch, block: int) -> None:
    monkeypatch.setattr(textlines, "_BLOCK", block)
    monkeypatch.setattr(textlines, "_HEAD_BLOCK", block)

    def over(text: bytes) -> str | None:
        return scan_lines(io.BytesIO(text), skip=0, max_bytes=999, max_lines=9, max_line_bytes=100).over

    assert over(b"a\n" + b"b" * 100 + b"\nc") is None
    assert over(b"a\n" + b"b" * 101 + b"\nc") == "line"
    assert over(b"a\n" + b"b" * 101) == "line"


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_a_cut_mcap_chunk_inflates_to_no_more_than_it_claims(compression: str) -> None:
    """Salvage of a chunk the file's end cut through was bounded only by the codec's ratio (zstd: 32768x)."""
    import lz4.frame

    bomb = bytes(64 << 20)
    packed = zstandard.ZstdCompressor().compress(bomb) if compression == "zstd" else lz4.frame.compress(bomb)
    cut = packed[:-8]
    tracemalloc.start()
    try:
        out = decompress(compression, cut, 1 << 20, partial=True)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert len(out) == 1 << 20
    assert peak < 8 << 20, f"{peak} bytes inflated for a 1 MiB claim"
