"""Deterministic, atomic, self-describing Parquet and JSON writes.

Every Parquet file carries, under the ``auvid`` metadata key, a JSON document with the schema version,
the package version and the provenance the writer passes in. Writes go to a temporary file beside the
target and are moved into place with :func:`os.replace`, so a reader never sees half a file.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline import SCHEMA_VERSION, __version__
from pipeline.errors import SchemaError

if TYPE_CHECKING:
    import pyarrow as pa

# pyarrow.parquet is imported by the functions that read or write Parquet: the config loader imports this module
# for canonical_json, and a command that only loads a config (or prints help) does not pay pyarrow's import.

META_KEY = b"auvid"

#: The name :func:`atomic_path` gives a temporary: ``.<target name>.<8 characters of mkstemp>.tmp`` beside the target.
TEMP_NAME = re.compile(r"^\.(?P<target>.+)\.[a-z0-9_]{8}\.tmp$")

log = logging.getLogger(__name__)


@contextmanager
def atomic_path(target: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; move it over ``target`` only if the block succeeds.

    An OSError that names no file (a full disk: ENOSPC from a write, Arrow's I/O errors) or only the temporary is
    raised again naming ``target``, so the message says which output could not be written.
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, target)
    except OSError as err:
        if err.filename in (None, str(tmp_path)):  # a full disk (ENOSPC) names no file: name the one being written
            raise OSError(err.errno, err.strerror or str(err), str(target)) from err
        raise
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def remove_stale_temps(directory: str | Path, *, targets: set[str] | None = None,
                       recursive: bool = False) -> list[Path]:
    """Remove the temporaries of :func:`atomic_path` that a killed writer left in ``directory``.

    Only files named as :data:`TEMP_NAME` says; with ``targets``, only those of these target names (a per-trial
    stage clears its own trial's, not a sibling worker's); ``recursive``: in sub-directories too. A stage calls it
    at start, when no writer of its own can be running (the run root's lock keeps other commands out).
    """
    directory = Path(directory)
    if not directory.is_dir():
        return []
    found = directory.rglob(".*.tmp") if recursive else directory.glob(".*.tmp")
    removed = []
    for path in sorted(found):
        match = TEMP_NAME.match(path.name)
        if match is None or (targets is not None and match["target"] not in targets):
            continue
        if path.is_symlink() or path.is_file():
            path.unlink(missing_ok=True)
            removed.append(path)
    if removed:
        log.warning("removed %d temporary file(s) a killed run left in %s: %s", len(removed), directory,
                    [p.name for p in removed[:5]])
    return removed


def file_sha256(path: str | Path, chunk_bytes: int = 1 << 20) -> str:
    """sha256 of a file's bytes (a bag directory: of its files in name order)."""
    path = Path(path)
    digest = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for file in files:
        if path.is_dir():
            digest.update(str(file.relative_to(path)).encode())
        with open(file, "rb") as handle:
            while chunk := handle.read(chunk_bytes):
                digest.update(chunk)
    return digest.hexdigest()


def canonical_json(obj: Any) -> str:
    """JSON with sorted keys and no whitespace variation: equal objects give equal bytes."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False, default=str)


def write_parquet(table: pa.Table, target: str | Path, provenance: dict[str, Any]) -> Path:
    """Write ``table`` atomically with schema version, package version and ``provenance`` in its metadata.

    Byte-identical output for identical input: fixed compression and encodings, no timestamps, sorted JSON
    metadata. zstd level 1: much less compression time than level 3 for a few per cent more bytes, which
    matters for ingest, the stage that grows with the logs. Each column is encoded as :func:`column_encodings`
    says (floats byte-stream-split, integers delta-packed): fewer bytes than plain encoding and less CPU, since
    zstd then works on bytes it can compress (figures: docs/benchmarks.md, "Parquet encodings").
    """
    import pyarrow.parquet as pq

    meta = {"schema_version": SCHEMA_VERSION, "package_version": __version__, **provenance}
    existing = dict(table.schema.metadata or {})
    existing[META_KEY] = canonical_json(meta).encode()
    table = table.replace_schema_metadata(existing)
    with atomic_path(target) as tmp:
        pq.write_table(table, tmp, compression="zstd", compression_level=1, use_dictionary=False,
                       column_encoding=column_encodings(table.schema), write_statistics=True, store_schema=True)
    return Path(target)


def column_encodings(schema: pa.Schema) -> dict[str, str]:
    """The Parquet encoding of each top-level column that has a better one than PLAIN: BYTE_STREAM_SPLIT for
    float32/float64 (sensor values: each byte plane compresses on its own, the exponents and high mantissa bytes
    well) and DELTA_BINARY_PACKED for integers, timestamps and durations (time stamps on a clock: small, regular
    steps). Both are standard Parquet encodings that pyarrow, DuckDB, polars and Spark read, and both give back
    the same bits (NaN payloads, -0.0, the int64 extremes); other types (bools, strings, nested) stay PLAIN."""
    import pyarrow as pa

    out: dict[str, str] = {}
    for f in schema:
        if pa.types.is_float32(f.type) or pa.types.is_float64(f.type):
            out[f.name] = "BYTE_STREAM_SPLIT"
        elif pa.types.is_integer(f.type) or pa.types.is_timestamp(f.type) or pa.types.is_duration(f.type):
            out[f.name] = "DELTA_BINARY_PACKED"
    return out


def read_meta(path: str | Path) -> dict[str, Any]:
    """The ``auvid`` metadata document of a Parquet file written by :func:`write_parquet`."""
    import pyarrow.parquet as pq

    schema = pq.read_schema(path)
    raw = (schema.metadata or {}).get(META_KEY)
    if raw is None:
        raise SchemaError("no auvid metadata; was this file written by auvid?", file=path)
    return json.loads(raw)


def read_parquet(path: str | Path) -> tuple[pa.Table, dict[str, Any]]:
    """Read a Parquet file and its ``auvid`` metadata."""
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    raw = (table.schema.metadata or {}).get(META_KEY)
    if raw is None:
        raise SchemaError("no auvid metadata; was this file written by auvid?", file=path)
    return table, json.loads(raw)


def write_json(obj: Any, target: str | Path) -> Path:
    """Write ``obj`` as indented, key-sorted JSON, atomically."""
    with atomic_path(target) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, sort_keys=True, ensure_ascii=False, default=str) + "\n")
    return Path(target)
