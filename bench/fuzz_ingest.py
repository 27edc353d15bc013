"""Fuzz the log readers with seeded mutations of small logs written by the libraries' own writers (issue 17).

    python bench/fuzz_ingest.py                          # 700 cases (50 per format), seed 0, ~30 s
    python bench/fuzz_ingest.py --cases 10000 --seed 1   # the long campaign
    python bench/fuzz_ingest.py --formats mcap-zstd,csv-gz --cases 500
    python bench/fuzz_ingest.py --replay mcap-zstd:17    # one case in-process, with its traceback
    python bench/fuzz_ingest.py --replay mcap-zstd:17 --keep /tmp/case   # and keep the mutated log
    python bench/fuzz_ingest.py --cases 10000 --seed 3601 --inspect --cpu-s 10 --mem-mib 2048 --timeout 60
                                                         # issue 36's campaign: `auvid inspect` too, CPU-limited

Seeds used so far: 0, 1, 2, 3 (issue 17), the issue-36 campaign's 10,000 cases (before its fixes), and 3601..
(issue 36's rerun, docs/benchmarks.md).

Seeds: the synthetic trial of ``tests/io/helpers.py`` (a custom DVL type, an Imu, a JointState) written as MCAP
(zstd, lz4, none, unchunked, no summary), ROS 1 (none, bz2, lz4, unindexed), ROS 2 (sqlite3, file-compressed
zstd, MCAP storage) and CSV (plain, gzip). Each case applies one mutation, drawn from ``random.Random`` seeded
with ``"{seed}:{format}:{index}"`` (so any case can be replayed alone): bit flips, a run of random bytes, a
zeroed region, an inserted or duplicated region, a whole record (MCAP, ROS 1) written twice, truncation, a huge
value written over a plausible length field, and for CSV a nasty number written over a value or a time stamp.

Each case is read (``open_log`` / ``open_text``, ``topics()``, ``read()`` of the test requests) in a forked child
with an address-space limit (``RLIMIT_AS``: the parent's size + ``--mem-mib``) and a wall-clock timeout. Outcome:

- ``ok``: read, every count as in the intact log;  ``reported``: read, with a salvage report, failed topics or
  dropped CSV rows that the intact log's read does not give (an unindexed ROS 1 bag always says it was cut);
  ``error``: a :class:`pipeline.errors.PipelineError` (a clean quarantine);
- ``uncaught``: any other exception;  ``memory``: MemoryError;  ``hang``: timeout;  ``crash``: the child died;
- ``silent-loss``: fewer messages than the intact log and nothing reported;  ``silent-dup``: more messages
  (binary formats only: a CSV states no count, so an inserted or cut line is a line like any other).

The table counts outcomes per format; distinct uncaught sites follow (innermost ``pipeline/`` frame and the
innermost frame), with a case to replay.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import random
import resource
import select
import shutil
import signal
import sys
import tempfile
import time
import traceback
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT)]

OUTCOMES = ["ok", "reported", "error", "uncaught", "memory", "hang", "crash", "silent-loss", "silent-dup"]
FORMATS = ["mcap-zstd", "mcap-lz4", "mcap-none", "mcap-unchunked", "mcap-nosummary", "ros1-none", "ros1-bz2",
           "ros1-lz4", "ros1-unindexed", "ros2-sqlite3", "ros2-zstd", "ros2-mcap", "csv", "csv-gz"]
HUGE = [(4, 0xFFFFFFFF), (4, 0x7FFFFFFF), (4, 0x80000000), (8, 1 << 40), (8, (1 << 63) + 5), (8, (1 << 64) - 1),
        (8, 1 << 62)]
NASTY_NUMBERS = [b"99999999999999999999", b"99999999999", b"1e300", b"-1", b"nan", b"inf", b"-0", b"1e-400",
                 b"0x10", b"", b"1.2.3", b"--5", b"1_000", b"\xff\xfe", b"9" * 400]
CSV_ROWS = 60


# -- seeds ---------------------------------------------------------------------------------------------------
def write_seed(fmt: str, where: Path) -> tuple[Path, Path]:
    """Write the intact log of ``fmt`` under ``where``: (the path to open, the file to mutate)."""
    from tests.io import helpers as h

    msgs = h.trial(n=10, seed=7)
    where.mkdir(parents=True, exist_ok=True)
    if fmt.startswith("mcap"):
        kw: dict[str, Any] = {"mcap-zstd": {}, "mcap-lz4": {"compression": "lz4"},
                              "mcap-none": {"compression": "none"},
                              "mcap-unchunked": {"chunked": False, "summary": False, "indexes": False},
                              "mcap-nosummary": {"summary": False}}[fmt]
        path = h.write_mcap(where / "t.mcap", msgs, **kw)
        return path, path
    if fmt.startswith("ros1"):
        comp = fmt.split("-")[1]
        if comp == "unindexed":
            path = h.write_rosbag1_unindexed(where / "t.bag", msgs, chunk_threshold=1500)
        else:
            path = h.write_rosbag1(where / "t.bag", msgs, compression=None if comp == "none" else comp,
                                   chunk_threshold=1500)
        return path, path
    if fmt.startswith("ros2"):
        kw = {"ros2-sqlite3": {}, "ros2-zstd": {"compression": "file"}, "ros2-mcap": {"storage": "mcap"}}[fmt]
        bag = h.write_rosbag2(where / "bag", msgs, **kw)
        storage = next(p for p in sorted(bag.iterdir()) if p.name != "metadata.yaml")
        return bag, storage
    trial = where / "trial"
    trial.mkdir()
    lines = ["t,u,v"] + [f"{1700000000 + i * 0.1:.6f},{i * 0.01:.4f},{-i * 0.02:.4f}" for i in range(CSV_ROWS)]
    text = ("\n".join(lines) + "\n").encode()
    if fmt == "csv-gz":
        import gzip

        path = trial / "dvl.csv.gz"
        path.write_bytes(gzip.compress(text, mtime=0))
    else:
        path = trial / "dvl.csv"
        path.write_bytes(text)
    return trial, path


# -- mutations -----------------------------------------------------------------------------------------------
def records(data: bytes) -> list[tuple[int, int]]:
    """(offset, length) of the top-level records of an MCAP file or a ROS 1 bag; [] for other data."""
    out: list[tuple[int, int]] = []
    if data.startswith(b"\x89MCAP0\r\n"):
        pos = 8
        while pos + 9 <= len(data) - 8:
            length = int.from_bytes(data[pos + 1:pos + 9], "little")
            out.append((pos, 9 + length))
            pos += 9 + length
    elif data.startswith(b"#ROSBAG V2.0\n"):
        pos = 13
        while pos + 4 <= len(data):
            head = int.from_bytes(data[pos:pos + 4], "little")
            if pos + 8 + head > len(data):
                break
            body = int.from_bytes(data[pos + 4 + head:pos + 8 + head], "little")
            out.append((pos, 8 + head + body))
            pos += 8 + head + body
    return [(at, size) for at, size in out if at + size <= len(data)]


def mutate(data: bytes, rng: random.Random, *, text: bool) -> tuple[bytes, str]:
    """One seeded mutation of ``data``: (new bytes, a short description)."""
    buf = bytearray(data)
    n = len(buf)
    kinds = ["bitflip", "bitflip", "run", "zero", "truncate", "huge", "huge", "insert", "duplicate"]
    if text:
        kinds += ["number", "number", "number"]
    recs = records(data)
    if recs:
        kinds += ["record"]
    kind = rng.choice(kinds)
    at = rng.randrange(n)
    if kind == "record":  # one whole record written twice (a chunk, a chunk info, a message index ...)
        at, size = rng.choice(recs)
        return bytes(buf[:at + size]) + bytes(buf[at:at + size]) + bytes(buf[at + size:]), \
            f"record of {size} B at {at} duplicated"
    if kind == "bitflip":
        spots = sorted(rng.randrange(n * 8) for _ in range(rng.randint(1, 4)))
        for bit in spots:
            buf[bit // 8] ^= 1 << (bit % 8)
        return bytes(buf), f"bitflip bits {spots}"
    if kind == "run":
        size = rng.randint(1, 64)
        buf[at:at + size] = bytes(rng.randrange(256) for _ in range(size))
        return bytes(buf[:n]), f"random run of {size} at {at}"
    if kind == "zero":
        size = rng.randint(1, 512)
        buf[at:at + size] = bytes(min(size, n - at))
        return bytes(buf), f"zeroed {size} at {at}"
    if kind == "truncate":
        return bytes(buf[:at]), f"truncated at {at}"
    if kind == "insert":
        size = rng.randint(1, 64)
        return bytes(buf[:at]) + bytes(rng.randrange(256) for _ in range(size)) + bytes(buf[at:]), \
            f"inserted {size} at {at}"
    if kind == "duplicate":
        size = rng.randint(1, 1024)
        return bytes(buf[:at + size]) + bytes(buf[at:at + size]) + bytes(buf[at + size:]), \
            f"duplicated {size} at {at}"
    if kind == "huge":
        width, value = rng.choice(HUGE)
        # a plausible length field: a little-endian value of that width in [1, file size]
        spots = [i for i in range(0, n - width + 1)
                 if 0 < int.from_bytes(buf[i:i + width], "little") <= n]
        at = rng.choice(spots) if spots else at
        buf[at:at + width] = value.to_bytes(width, "little")
        return bytes(buf[:n]), f"huge {value:#x} ({width} B) at {at}"
    # number: a nasty token over a field of a CSV line
    bounds = [i + 1 for i, b in enumerate(buf) if b in b",\n"]
    start = rng.choice([0, *bounds[:-1]])
    end = start
    while end < n and buf[end] not in b",\n":
        end += 1
    token = rng.choice(NASTY_NUMBERS)
    return bytes(buf[:start]) + token + bytes(buf[end:]), f"number {token[:24]!r} at {start}"


def case_rng(seed: int, fmt: str, index: int) -> random.Random:
    return random.Random(f"{seed}:{fmt}:{index}")


# -- reading one log -----------------------------------------------------------------------------------------
def read_counts(fmt: str, path: Path) -> tuple[dict[str, int], Any]:
    """Open and read the log: (messages read per topic, what the read reported: a salvage report, failed topics,
    dropped CSV rows; None when nothing)."""
    if fmt.startswith("csv"):
        from pipeline.config.sources import CsvOptions
        from pipeline.io.text import open_text

        with open_text(path) as reader:
            names = list(reader.topics())
            result = reader.read({n: ["u", "v"] for n in names},
                                 csv_options={n: CsvOptions(time_column="t") for n in names})
        dropped = sum(getattr(d, "dropped_count", 0) for d in result.topics.values())
        reported = (result.salvage and (result.salvage.reason, result.salvage.kept), dropped) \
            if result.salvage is not None or dropped else None
    else:
        from pipeline.io import open_log
        from tests.io import helpers as h

        with open_log(path) as reader:
            listed = reader.topics()
            result = reader.read({t: f for t, f in h.REQUESTS.items() if t in listed})
        reported = (result.salvage and (result.salvage.reason, result.salvage.kept), sorted(result.failed)) \
            if result.salvage is not None or result.failed else None
    return {t: len(d.log_ns) for t, d in result.topics.items()}, reported


def classify(fmt: str, path: Path, baseline: dict[str, int], intact_report: Any = None) -> dict[str, Any]:
    """Read one (mutated) log in this process; the outcome and, for an uncaught exception, its site.

    A report counts when it says something the intact log's read does not (an unindexed ROS 1 bag always
    reports that it was cut; its loss must change what is reported)."""
    from pipeline.errors import PipelineError

    try:
        counts, report = read_counts(fmt, path)
        reported = report is not None and report != intact_report
    except PipelineError as err:
        return {"outcome": "error", "detail": str(err)[:200]}
    except MemoryError as err:
        return {"outcome": "memory", **_site(err)}
    except Exception as err:  # noqa: BLE001 - what the campaign looks for
        return {"outcome": "uncaught", **_site(err)}
    if fmt.startswith("csv"):  # plain text states no count: an inserted or cut line is a line like any other
        return {"outcome": "reported" if reported else "ok"}
    if any(counts.get(t, 0) > n for t, n in baseline.items()):
        return {"outcome": "silent-dup", "detail": str(counts)}
    if reported:
        return {"outcome": "reported"}
    if any(t in counts and counts[t] < n for t, n in baseline.items()):
        return {"outcome": "silent-loss", "detail": str(counts)}
    return {"outcome": "ok"}


def _site(err: BaseException) -> dict[str, str]:
    frames = traceback.extract_tb(err.__traceback__)
    ours = [f for f in frames if "/pipeline/" in f.filename]

    def where(f: traceback.FrameSummary) -> str:
        name = f.filename.split("/site-packages/")[-1] if "site-packages" in f.filename \
            else str(Path(f.filename).relative_to(ROOT)) if f.filename.startswith(str(ROOT)) else f.filename
        return f"{name}:{f.lineno} {f.name}"

    kind = type(err).__qualname__
    if type(err).__module__ not in ("builtins", "exceptions"):
        kind = f"{type(err).__module__}.{kind}"
    site = f"{kind} at {where(ours[-1]) if ours else '?'}"
    if frames and (not ours or frames[-1] is not ours[-1]):
        site += f" <- {where(frames[-1])}"
    return {"site": site, "detail": f"{type(err).__name__}: {str(err)[:160]}"}


def classify_inspect(path: Path) -> dict[str, Any]:
    """``auvid inspect --json PATH`` in this process (its output thrown away): exit 0 is ``ok``; 2 or 3 (a usage
    error or a clean one-line failure) is ``error``; an exception out of the CLI is ``uncaught`` / ``memory``."""
    from pipeline.cli import main as auvid

    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.dup2(devnull, 2)
    try:
        code = auvid(["inspect", str(path), "--json"])
    except MemoryError as err:
        return {"outcome": "memory", **_site(err)}
    except Exception as err:  # noqa: BLE001 - what the campaign looks for
        return {"outcome": "uncaught", **_site(err)}
    return {"outcome": "ok" if code == 0 else "error", "detail": f"exit {code}"}


def run_forked(fmt: str, path: Path, baseline: dict[str, int], intact_report: Any, timeout_s: float,
               mem_limit: int, cpu_s: int = 0, job: str = "read") -> dict[str, Any]:
    """:func:`classify` (``job`` read) or :func:`classify_inspect` (``job`` inspect) in a forked child under an
    address-space limit, a CPU-time limit (``cpu_s``, 0: none; SIGXCPU is a ``hang``) and a wall-clock timeout."""
    rfd, wfd = os.pipe()
    pid = os.fork()
    if pid == 0:  # child
        os.close(rfd)
        code = 0
        try:
            resource.setrlimit(resource.RLIMIT_AS, (mem_limit, mem_limit))
            if cpu_s:
                resource.setrlimit(resource.RLIMIT_CPU, (cpu_s, cpu_s + 5))
            out = classify(fmt, path, baseline, intact_report) if job == "read" else classify_inspect(path)
            with os.fdopen(wfd, "w") as fh:
                fh.write(json.dumps(out))
        except BaseException:  # noqa: BLE001 - never return into the parent's code
            code = 3
        os._exit(code)
    os.close(wfd)
    chunks: list[bytes] = []
    deadline = time.monotonic() + timeout_s
    with os.fdopen(rfd, "rb") as fh:
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fh], [], [], left)[0]:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                return {"outcome": "hang", "detail": f"no answer in {timeout_s} s"}
            chunk = os.read(fh.fileno(), 65536)
            if not chunk:
                break
            chunks.append(chunk)
    _, status = os.waitpid(pid, 0)
    if chunks:
        return json.loads(b"".join(chunks))
    if os.WIFSIGNALED(status) and os.WTERMSIG(status) in (signal.SIGXCPU, signal.SIGKILL) and cpu_s:
        return {"outcome": "hang", "detail": f"over {cpu_s} s of CPU"}
    how = f"signal {os.WTERMSIG(status)}" if os.WIFSIGNALED(status) else f"exit {os.WEXITSTATUS(status)}"
    return {"outcome": "crash", "detail": how}


def _vm_size() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmSize:"):
            return int(line.split()[1]) * 1024
    return 0


# -- campaign ------------------------------------------------------------------------------------------------
def prepare(fmt: str, seeds: Path) -> tuple[Path, Path, dict[str, int], Any]:
    """The intact seed: (path to open, file to mutate, counts, what its read reports)."""
    log_path, target = write_seed(fmt, seeds / fmt)
    counts, report = read_counts(fmt, log_path)
    assert report is None or fmt == "ros1-unindexed", f"{fmt}: the intact seed reads with a report: {report}"
    return log_path, target, counts, report


def apply_case(fmt: str, index: int, seed: int, log_path: Path, target: Path, work: Path) -> tuple[Path, str]:
    """Copy the intact log into ``work`` and mutate its copy of ``target``: (the path to open, description)."""
    if work.exists():
        shutil.rmtree(work)
    base = log_path if log_path.is_dir() else log_path.parent
    shutil.copytree(base, work)
    rng = case_rng(seed, fmt, index)
    victim = work / target.relative_to(base)
    if fmt.startswith("ros2") and rng.random() < 0.15:
        victim = work / "metadata.yaml"
    new, what = mutate(victim.read_bytes(), rng, text=fmt == "csv")
    victim.write_bytes(new)
    return work / log_path.relative_to(base) if not log_path.is_dir() else work, f"{victim.name}: {what}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=50 * len(FORMATS), help="cases in all, spread over the formats")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--formats", default=",".join(FORMATS))
    ap.add_argument("--timeout", type=float, default=10.0, help="seconds per case")
    ap.add_argument("--mem-mib", type=int, default=1024, help="address space a case may add to the parent's")
    ap.add_argument("--cpu-s", type=int, default=0, help="CPU seconds a case may use (0: no limit but --timeout)")
    ap.add_argument("--inspect", action="store_true", help="also run `auvid inspect --json` on every case, in a "
                    "child of its own under the same limits")
    ap.add_argument("--replay", help="FORMAT:INDEX: run one case in-process and show its traceback")
    ap.add_argument("--keep", type=Path, help="with --replay: copy the mutated log here")
    ap.add_argument("--json", type=Path, help="write every case's outcome here")
    ap.add_argument("--verbose", action="store_true", help="print every case that is not ok")
    args = ap.parse_args(argv)
    logging.getLogger().addHandler(logging.NullHandler())  # the readers' warnings are not the result
    formats = [f for f in args.formats.split(",") if f]
    unknown = set(formats) - set(FORMATS)
    if unknown:
        ap.error(f"unknown formats {sorted(unknown)}; known: {FORMATS}")

    with tempfile.TemporaryDirectory(prefix="fuzz-ingest-") as tmp:
        seeds, work = Path(tmp) / "seeds", Path(tmp) / "case"
        if args.replay:
            fmt, index = args.replay.rsplit(":", 1)
            log_path, target, baseline, intact_report = prepare(fmt, seeds)
            path, what = apply_case(fmt, int(index), args.seed, log_path, target, work)
            print(f"{fmt}:{index}  {what}")
            if args.keep:
                shutil.copytree(work, args.keep, dirs_exist_ok=True)
            try:
                print(read_counts(fmt, path), "intact:", baseline)
            except Exception:  # noqa: BLE001 - show it
                traceback.print_exc()
            print(classify(fmt, path, baseline, intact_report))
            return 0
        prepared = {fmt: prepare(fmt, seeds) for fmt in formats}
        mem_limit = _vm_size() + (args.mem_mib << 20)
        per_format = {fmt: args.cases // len(formats) + (i < args.cases % len(formats))
                      for i, fmt in enumerate(formats)}
        table: dict[str, Counter[str]] = {fmt: Counter() for fmt in formats}
        inspected: dict[str, Counter[str]] = {fmt: Counter() for fmt in formats}
        sites: dict[str, list[str]] = defaultdict(list)
        records = []
        t0 = time.monotonic()
        for fmt in formats:
            log_path, target, baseline, intact_report = prepared[fmt]
            for index in range(per_format[fmt]):
                path, what = apply_case(fmt, index, args.seed, log_path, target, work)
                out = run_forked(fmt, path, baseline, intact_report, args.timeout, mem_limit, args.cpu_s)
                table[fmt][out["outcome"]] += 1
                records.append({"case": f"{fmt}:{index}", "mutation": what, **out})
                outs = [("", out)]
                if args.inspect:
                    seen = run_forked(fmt, path, baseline, intact_report, args.timeout, mem_limit, args.cpu_s,
                                      job="inspect")
                    inspected[fmt][seen["outcome"]] += 1
                    records[-1]["inspect"] = seen
                    outs.append(("inspect: ", seen))
                for label, got in outs:
                    if got["outcome"] not in ("ok", "reported", "error"):
                        sites[label + (got.get("site") or f"{got['outcome']}: {got.get('detail', '')[:80]}")].append(
                            f"{fmt}:{index}")
                        if args.verbose:
                            print(f"{fmt}:{index} {what}: {label}{got}")
        elapsed = time.monotonic() - t0

    shown = [o for o in OUTCOMES if any(table[f][o] for f in formats)] or OUTCOMES[:1]
    cpu = f", {args.cpu_s} s of CPU" if args.cpu_s else ""
    print(f"seed {args.seed}, {sum(per_format.values())} cases, {elapsed:.0f} s, "
          f"limit {args.timeout:g} s wall{cpu} and +{args.mem_mib} MiB address space per case\n")
    seen_shown = [o for o in OUTCOMES if any(inspected[f][o] for f in formats)] if args.inspect else []
    print("| format | " + " | ".join([*shown, *(f"inspect {o}" for o in seen_shown)]) + " |")
    print("| --- | " + " | ".join("---:" for _ in [*shown, *seen_shown]) + " |")
    for fmt in [*formats, "all"]:
        row = sum(table.values(), Counter()) if fmt == "all" else table[fmt]
        irow = sum(inspected.values(), Counter()) if fmt == "all" else inspected[fmt]
        print(f"| {fmt} | " + " | ".join([*(str(row[o]) for o in shown), *(str(irow[o]) for o in seen_shown)])
              + " |")
    if sites:
        print("\nnot clean (site: count, first case):")
        for site, cases in sorted(sites.items(), key=lambda kv: -len(kv[1])):
            print(f"  {len(cases):4d}  {site}   e.g. --replay {cases[0]}")
    if args.json:
        args.json.write_text(json.dumps(records, indent=1))
    return 1 if sites else 0


if __name__ == "__main__":
    sys.exit(main())
