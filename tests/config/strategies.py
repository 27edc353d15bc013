"""Hypothesis strategies over the params and vehicle configs (issue 36, item 3), shared by the in-suite campaign
(``tests/config/test_config_property.py``) and the long one (``bench/fuzz_configs.py``).

A generated config is a real one (the repository's ``params.yaml``; the example vehicle with a CSV stream, a
``time: {rate_hz}`` stream and a trial override added) with one to three edits: a value anywhere (a leaf, a list
or a whole section) replaced by a number at or beyond any plausible bound (0, -1, 1e-300, 1e300, inf, nan,
2**63, 2**70 ...), the old value scaled by such a factor, a wrong type, an empty or huge list, a path to a
special file; a key dropped; an unknown key added. :func:`outcome` loads it and says how it went.
"""

from __future__ import annotations

import copy
import math
import random
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import yaml
from hypothesis import strategies as st

from pipeline.config import check_params_against_vehicle, load_params, load_vehicle
from pipeline.errors import ConfigError
from pipeline.sim.writers import csv_column

ROOT = Path(__file__).resolve().parents[2]
#: The example's params (the repository's params.yaml) with every key spelled out: the campaigns edit a whole config.
PARAMS: dict[str, Any] = load_params(ROOT / "params.yaml").model_dump(mode="json")
VEHICLE: dict[str, Any] = yaml.safe_load((ROOT / "pipeline" / "sim" / "dagon.yaml").read_text(encoding="utf-8"))
VEHICLE["streams"]["tank"] = {"file": "tank.csv", "clock": "column", "optional": True,
                              "csv": {"time_column": "t", "skip_rows": 0, "encoding": "utf-8", "delimiter": ",",
                                      "time_unit": "s", "time_origin": "relative", "epoch_s": 1.7e9},
                              "signals": {"x_tank_m": {"field": "x", "unit": "m"}}}
VEHICLE["streams"]["fog"]["time"] = {"rate_hz": 100.0}  # the FOG's rate (read in the CSV trial)
VEHICLE["trials"] = {"trial01": {"streams": {"fog": {"offset_s": 0.01}}}}
#: The run campaign's trial of mixed formats: a directory of CSV exports (``pipeline.sim.writers``' csv layout, the
#: AHRS quaternion as its four columns) with the ``tank`` table beside them, so ``csv:`` options are really read.
CSV_TRIAL = "trial02"


def _csv_override(name: str, stream: dict[str, Any]) -> dict[str, Any]:
    """A topic stream read from its CSV export in :data:`CSV_TRIAL` (the writers' ``<stream>.csv``)."""
    return {"topic": None, "file": f"{name}.csv", "clock": "column",
            "csv": {"time_column": "log_ns" if stream["clock"] == "log" else "stamp_ns", "time_unit": "ns",
                    "time_origin": "absolute"},
            "signals": {signal: {**source, "field": csv_column(source["field"])}
                        for signal, source in stream["signals"].items()}}


VEHICLE["trials"][CSV_TRIAL] = {"streams": {name: _csv_override(name, stream)
                                            for name, stream in VEHICLE["streams"].items() if "topic" in stream}}

INF, NAN = math.inf, math.nan
EXTREMES = [0, -1, 1, 0.0, -0.0, 1e-300, -1e-300, 5e-324, 1e300, -1e300, 1.7976931348623157e308, INF, -INF, NAN,
            2**31, 2**32, 2**53 + 1, 2**63, 2**64, 2**70, -(2**63) - 1, 1e9, 1e6, 0.99999, 1.00001]
FACTORS = [0.0, -1.0, 1e-300, 1e-9, 0.5, 2.0, 1e9, 1e300, INF, NAN]
CODECS = ["rot13", "base64", "hex", "zlib", "bz2", "uu", "quopri", "utf-16", "utf-32-be", "latin-1", "idna",
          "unicode_escape", "utf-8-sig", "mbcs", "undefined"]
PATHS = ["/", "/proc", "/dev/zero", "/dev/null", "/proc/self/mem", "../../etc/passwd", ".", "nonexistent.csv"]
STRINGS = ["", " ", "auto", "none", "\x00", "TODO", "1e9", "nan", "ü" * 3, "a" * 5000, "*", "{x}", "${vehicle}",
           "trial01", "u_mps", "ls", *PATHS, *CODECS[:4]]
# Strings that mean something for a key of this name: the values a user would mistype or a hostile file would give
KEYED_STRINGS = {"encoding": CODECS, "table": PATHS, "message_definitions": PATHS, "file": [*PATHS, "*", "**/*"],
                 "delimiter": ["", "  ", "\n", "\r", "\"", "ab", "\x00", ",,"],
                 "time_unit": ["ns", "s", "min", "h", "", "S"], "time_column": ["", " ", "\x00"]}


def _paths(doc: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every key path of ``doc``: sections, lists and leaves (not the root)."""
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for key, value in doc.items():
            out += _paths(value, (*prefix, key))
    elif isinstance(doc, list):
        for i, value in enumerate(doc):
            out += _paths(value, (*prefix, i))
    return out


def _get(doc: Any, path: tuple[Any, ...]) -> Any:
    for part in path:
        doc = doc[part]
    return doc


Pick = Callable[[Sequence[Any]], Any]  # one element of a sequence: Hypothesis' draw, or random.Random.choice


def _number(old: Any, pick: Pick) -> Any:
    """At and beyond bounds: an extreme, the old value scaled by an extreme factor, or a float of any exponent."""
    how = pick(["extreme", "extreme", "scaled", "any"] if _is_number(old) else ["extreme", "any"])
    if how == "extreme":
        return pick(EXTREMES)
    if how == "scaled":
        return old * pick(FACTORS)
    return pick([-1.0, 1.0]) * pick([1.0, 1.5, 3.7, 9.99]) * 10.0 ** pick(range(-320, 309, 7))


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def new_value(old: Any, key: Any, pick: Pick) -> Any:
    """A replacement for ``old`` (at ``key``): mostly of its kind (numbers at and beyond bounds; strings that mean
    something for ``key``, odd ones), else a wrong type, an empty / huge list, a mapping."""
    strings = [*KEYED_STRINGS.get(key, []), *STRINGS]

    def scalar() -> Any:
        kind = pick(["number", "string", "bool", "none"])
        return _number(old, pick) if kind == "number" else pick(strings) if kind == "string" else \
            pick([True, False]) if kind == "bool" else None

    kind = pick(["typed", "typed", "typed", "scalar", "list", "container", "mapping"])
    if kind == "typed":
        return pick(strings) if isinstance(old, str) or key in KEYED_STRINGS else _number(old, pick)
    if kind == "scalar":
        return scalar()
    if kind == "list":
        return [scalar() for _ in range(pick(range(9)))]
    if kind == "container":
        return copy.deepcopy(pick([[], {}, [[]], [1.0] * 10_000, list(range(2000)), {"x": 1}, [NAN, NAN, NAN]]))
    return {pick(["default", "x", "trial01", "u_mps", "", "0"]): scalar() for _ in range(pick(range(4)))}


def edit(base: dict[str, Any], pick: Pick) -> tuple[dict[str, Any], list[str]]:
    """``base`` with one to three edits, and what was edited (dotted keys). Every key shape is as likely as any
    other (a 6x6 matrix is one shape, not 36 keys): set (4 in 6), dropped, or an unknown key beside it."""
    doc = copy.deepcopy(base)
    what: list[str] = []
    for _ in range(pick([1, 2, 3])):
        groups: dict[tuple[Any, ...], list[tuple[Any, ...]]] = {}
        for p in _paths(doc):
            groups.setdefault(tuple("*" if isinstance(k, int) else k for k in p), []).append(p)
        path = pick(sorted(groups[pick(sorted(groups, key=str))]))
        parent = _get(doc, path[:-1])
        key = path[-1]
        op = pick(["set", "set", "set", "set", "drop", "unknown"])
        dotted = ".".join(map(str, path))
        if op == "drop":
            if isinstance(parent, list):
                parent.pop(key)
            else:
                del parent[key]
            what.append(f"drop {dotted}")
        elif op == "unknown" and isinstance(parent, dict):
            parent[pick(["typo", "rate", "Rate_hz", "seed_", "x"])] = 1
            what.append(f"unknown key beside {dotted}")
        else:
            name = key if isinstance(key, str) else path[-2] if len(path) > 1 else None
            parent[key] = new_value(parent[key], name, pick)
            what.append(f"{dotted} = {_short(parent[key])}")
    return doc, what


@st.composite
def edited(draw: st.DrawFn, base: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """Hypothesis' strategy of :func:`edit` (each pick a draw: shrinkable, replayable)."""
    return edit(base, lambda seq: draw(st.sampled_from(seq)))


def random_edit(base: dict[str, Any], rng: random.Random) -> tuple[dict[str, Any], list[str]]:
    """:func:`edit` with picks from ``rng`` (uniform: the long campaign's generator)."""
    return edit(base, rng.choice)


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:37]}..."


def write(path: Path, doc: dict[str, Any]) -> Path:
    path.write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


def outcome(kind: str, path: Path, vehicle: Path | None = None, time_limit_s: float = 5.0) -> tuple[str, str]:
    """Load ``path`` as ``kind`` (params: checked against the example vehicle too): ``loaded``; ``refused`` (a
    ConfigError naming the file and a key); else ``unnamed`` (a ConfigError without both), ``uncaught`` (any
    other exception) or ``slow`` (over ``time_limit_s``), each with a detail."""
    t0 = time.monotonic()
    try:
        if kind == "params":
            params = load_params(path)
            check_params_against_vehicle(load_vehicle(vehicle or ROOT / "pipeline" / "sim" / "dagon.yaml"),
                                         params, path)
        else:
            veh = load_vehicle(path)
            check_params_against_vehicle(veh, load_params(ROOT / "params.yaml"), ROOT / "params.yaml")
            for trial in veh.trials:
                veh.for_trial(trial)
        result = ("loaded", "")
    except ConfigError as err:
        named = err.file == str(path) and str(path) in str(err) and bool(err.field)
        result = ("refused", f"{err.field}") if named else ("unnamed", str(err)[:200])
    except Exception as err:  # noqa: BLE001 - what the campaign looks for
        result = ("uncaught", f"{type(err).__name__}: {str(err)[:200]}")
    if time.monotonic() - t0 > time_limit_s:
        return "slow", f"{time.monotonic() - t0:.1f} s; {result[0]} {result[1]}"
    return result
