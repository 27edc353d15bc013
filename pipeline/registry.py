"""The model registry of scheduled retraining: one JSON document, written atomically.

Layout of a retraining home (``ROOT``)::

    ROOT/registry.json        this document (the single commit point: nothing counts until it says so)
    ROOT/stores/<version>/    the run directory (data/raw, data/signals, ..., data/models, reports/) built
                              for a version; the registry's ``store`` names the current one
    ROOT/models/<version>/    the models, evaluation and report of every candidate (promoted or not)
    ROOT/current              symlink to models/<current version> (a convenience; the registry is the truth)
    ROOT/staging/             candidates under construction (removed at the start of the next run)

The document::

    {"format": 1, "current": "v0002" | null, "store": "stores/v0003" | null,
     "aliases": {"champion": {"udot_mps2": {"version": "v0003", "model": "coupled_wdse_svr"}, ...}},
     "holdout": {"trials": [...], "logs": {trial: sha256}, "metric": "...", "mode": "max"},
     "seen_logs": {sha256: {"name": ..., "trial": ..., "version": ..., "seen_at": ...}},
     "versions": [{"version", "created_at", "status": "promoted" | "rejected" | "rolled_back", "reason",
                   "metrics", "holdout_score", "parent", "lineage": {...},
                   "events": [{"at", "action": "promote" | "rollback", "from", "to", "note"}]}]}

``status`` and ``reason`` are what retraining decided; :func:`promote` and :func:`rollback` (``auvid models
promote|rollback``) change ``current`` by hand, set ``status`` and append an event to the versions involved,
keeping retraining's ``reason``. :func:`promote_model` (``auvid models promote VERSION --model NAME [--output
COL]``) points an alias (default ``champion``) at one model of a version for some of its outputs only, leaving
``current`` and the other outputs as they are; ``auvid.load(ROOT, alias="champion")`` loads what it names. They
all take the same lock as a retrain (``ROOT/.retrain.lock``), so a manual
promotion cannot interleave with a cron retrain's commit.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from pipeline.errors import PipelineError
from pipeline.tableio import write_json
from pipeline.vocabulary import DOFS, acceleration_column

log = logging.getLogger(__name__)

FORMAT = 1
REGISTRY_FILE = "registry.json"
LOCK_FILE = ".retrain.lock"


class RegistryError(PipelineError):
    """The registry document is unreadable or of an unknown format."""


class UnknownVersion(RegistryError):
    """A version that the registry does not list, or that cannot become current (a usage error)."""


class LockBusy(Exception):
    """Another process (a retrain, a promotion) holds ``ROOT/.retrain.lock``."""


@contextmanager
def exclusive_lock(root: Path) -> Iterator[None]:
    """Hold ``ROOT/.retrain.lock`` (flock, non-blocking); raises LockBusy if another process has it."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    handle = open(root / LOCK_FILE, "a+")  # noqa: SIM115 - held for the whole run
    try:
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise LockBusy from None
        handle.seek(0)
        handle.truncate()
        handle.write(f"{os.getpid()}\n")
        handle.flush()
        try:
            yield
        finally:
            fcntl.flock(handle.fileno(), fcntl.LOCK_UN)
    finally:
        handle.close()


def empty() -> dict[str, Any]:
    return {"format": FORMAT, "current": None, "store": None, "holdout": None, "seen_logs": {}, "versions": [],
            "aliases": {}}


def registry_path(root: str | Path) -> Path:
    return Path(root) / REGISTRY_FILE


def load(root: str | Path) -> dict[str, Any]:
    """The registry of ``root`` (an empty one if there is none yet)."""
    path = registry_path(root)
    if not path.exists():
        return empty()
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        raise RegistryError(f"cannot read the registry: {err}", file=path) from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise RegistryError(f"unknown registry format {data.get('format') if isinstance(data, dict) else data!r}; "
                            f"expected {FORMAT}", file=path)
    return {**empty(), **data}


def save(root: str | Path, data: dict[str, Any]) -> Path:
    """Write the registry atomically (temp file + ``os.replace``): readers see the old or the new, never half."""
    path = write_json(data, registry_path(root))
    path.chmod(0o644)  # mkstemp makes 0600; dashboards and other users read the registry
    return path


def next_version(data: dict[str, Any]) -> str:
    numbers = [int(v["version"].lstrip("v")) for v in data["versions"] if str(v.get("version", "")).startswith("v")]
    return f"v{max(numbers, default=0) + 1:04d}"


def version(data: dict[str, Any], name: str | None) -> dict[str, Any] | None:
    return next((v for v in data["versions"] if v["version"] == name), None) if name else None


def current(data: dict[str, Any]) -> dict[str, Any] | None:
    """The entry of the current (promoted) model, or None."""
    return version(data, data.get("current"))


def current_model_dir(root: str | Path) -> Path | None:
    """Directory of the current model's artifacts, from the registry (not the convenience symlink)."""
    data = load(root)
    return Path(root) / "models" / data["current"] if data.get("current") else None


def point_current(root: str | Path, name: str) -> None:
    """Atomically repoint the ``current`` symlink at ``models/<name>``."""
    root = Path(root)
    tmp = root / f".current.{os.getpid()}.tmp"
    if tmp.is_symlink() or tmp.exists():
        tmp.unlink()
    os.symlink(Path("models") / name, tmp)
    os.replace(tmp, root / "current")


# ------------------------------------------------------------------------------------- promote and roll back

def require_version(data: dict[str, Any], name: str, root: str | Path) -> dict[str, Any]:
    """The entry of ``name``; UnknownVersion (listing the known ones) if the registry has none."""
    entry = version(data, name)
    if entry is None:
        known = [v["version"] for v in data["versions"]]
        raise UnknownVersion(f"unknown model version {name!r}; registered: {known or 'none'}",
                             file=registry_path(root))
    return entry


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def _switch(root: Path, data: dict[str, Any], target: str, action: str, note: str) -> dict[str, Any]:
    """Make ``target`` current in ``data`` (a copy), write it atomically, then repoint the ``current`` link."""
    if not (root / "models" / target).is_dir():
        raise UnknownVersion(f"version {target} has no model directory {root / 'models' / target}; it cannot "
                             "become current", file=registry_path(root))
    old = data.get("current")
    event = {"at": _now(), "action": action, "from": old, "to": target, "note": note}
    versions = []
    for v in data["versions"]:
        if v["version"] == target:
            v = {**v, "status": "promoted", "events": [*v.get("events", []), event]}
        elif v["version"] == old:
            v = {**v, "status": "rolled_back" if action == "rollback" else v["status"],
                 "events": [*v.get("events", []), event]}
        versions.append(v)
    data = {**data, "current": target, "versions": versions}
    save(root, data)  # the commit point
    point_current(root, target)
    log.info("registry %s: %s -> %s (%s)", action, old, target, note)
    return data


def promote(root: str | Path, name: str, note: str = "promoted by hand") -> dict[str, Any]:
    """Make a registered version current (under the retrain lock). Returns the new document; promoting the
    current version changes nothing. UnknownVersion for a version the registry does not list; LockBusy while a
    retrain runs."""
    root = Path(root)
    with exclusive_lock(root):
        data = load(root)
        require_version(data, name, root)
        if data.get("current") == name:
            return data
        return _switch(root, data, name, "promote", note)


def rollback(root: str | Path, note: str = "rolled back by hand") -> dict[str, Any]:
    """Return to the current version's parent: the model that was current when it was trained (under the
    retrain lock). UnknownVersion when there is no current version or it has no parent."""
    root = Path(root)
    with exclusive_lock(root):
        data = load(root)
        cur = current(data)
        if cur is None:
            raise UnknownVersion("no current model to roll back from", file=registry_path(root))
        parent = cur.get("parent")
        if not parent:
            raise UnknownVersion(f"{cur['version']} has no parent (it was the first model); nothing to roll back "
                                 "to", file=registry_path(root))
        require_version(data, parent, root)
        return _switch(root, data, parent, "rollback", f"{note} from {cur['version']}")


# ----------------------------------------------------------------------------------- per-model promotion

def model_outputs(root: str | Path, name: str, model: str) -> list[str]:
    """The outputs (acceleration columns) model ``model`` of version ``name`` predicts, from its cards:
    ``coupled_<m>``: the card's ``outputs``; a decoupled model ``<m>``: one per DOF it was fitted for."""
    base = Path(root) / "models" / name / "data" / "models"
    if model.startswith("coupled_"):
        card = base / "coupled" / f"{model.removeprefix('coupled_')}.card.json"
        try:
            outputs = json.loads(card.read_text(encoding="utf-8")).get("outputs") if card.is_file() else None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
            outputs = None
        return [str(o) for o in outputs] if isinstance(outputs, list) else []
    return [acceleration_column(d) for d in DOFS if (base / "decoupled" / f"{d}_{model}.card.json").is_file()]


def _known_models(root: Path, name: str) -> list[str]:
    base = root / "models" / name / "data" / "models"
    coupled = [f"coupled_{p.name.removesuffix('.card.json')}" for p in (base / "coupled").glob("*.card.json")]
    decoupled = {p.name.removesuffix(".card.json").split("_", 1)[1] for p in (base / "decoupled").glob("*_*.card.json")}
    return sorted(coupled + sorted(decoupled))


def promote_model(root: str | Path, name: str, model: str, outputs: list[str] | None = None,
                  alias: str = "champion", note: str = "promoted by hand") -> dict[str, Any]:
    """Point ``alias`` at model ``model`` of version ``name`` for ``outputs`` (default: every output it has),
    under the retrain lock; ``current`` and the alias's other outputs are left as they are. UnknownVersion for a
    version, model or output the registry's files do not have."""
    root = Path(root)
    with exclusive_lock(root):
        data = load(root)
        require_version(data, name, root)
        have = model_outputs(root, name, model)
        if not have:
            raise UnknownVersion(f"version {name} has no model {model!r}; its models: "
                                 f"{_known_models(root, name) or 'none'}", file=root / "models" / name)
        wanted = list(outputs) if outputs else have
        unknown = [o for o in wanted if o not in have]
        if unknown:
            raise UnknownVersion(f"model {model!r} of {name} predicts {have}, not {unknown}", file=registry_path(root))
        table = dict((data.get("aliases") or {}).get(alias) or {})
        before = {o: table.get(o) for o in wanted}
        table.update({o: {"version": name, "model": model} for o in wanted})
        event = {"at": _now(), "action": "promote_model", "alias": alias, "model": model, "outputs": wanted,
                 "from": before, "to": name, "note": note}
        versions = [{**v, "events": [*v.get("events", []), event]} if v["version"] == name else v
                    for v in data["versions"]]
        data = {**data, "aliases": {**(data.get("aliases") or {}), alias: dict(sorted(table.items()))},
                "versions": versions}
        save(root, data)
        log.info("registry %s: %s of %s for %s", alias, model, name, wanted)
        return data


def resolve_alias(data: dict[str, Any], alias: str, root: str | Path) -> dict[str, dict[str, str]]:
    """``{output: {"version", "model"}}`` of ``alias``; UnknownVersion (listing the aliases) if there is none."""
    table = (data.get("aliases") or {}).get(alias)
    if not table:
        known = sorted(data.get("aliases") or {}) or "none"
        raise UnknownVersion(f"no alias {alias!r} in the registry; aliases: {known}"
                             " (set one with `auvid models promote VERSION --model NAME`)", file=registry_path(root))
    return dict(table)


def lineage_chain(data: dict[str, Any], name: str) -> list[str]:
    """``name``, its parent, the parent's parent, ... (stops at a cycle or an unknown parent)."""
    chain: list[str] = []
    entry = version(data, name)
    while entry is not None and entry["version"] not in chain:
        chain.append(entry["version"])
        entry = version(data, entry.get("parent"))
    return chain


# ------------------------------------------------------------------------------------------------- views

def _score(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, (int, float)) and not isinstance(value, bool) else "-"


def rows(data: dict[str, Any]) -> list[dict[str, Any]]:
    """One record per version, oldest first: what ``auvid models list --json`` prints."""
    return [{"version": v["version"], "current": v["version"] == data.get("current"), "status": v.get("status"),
             "created_at": v.get("created_at"), "holdout_score": v.get("holdout_score"), "parent": v.get("parent"),
             "reason": v.get("reason")} for v in data["versions"]]


def format_table(data: dict[str, Any]) -> str:
    """The versions as an aligned text table, the current one marked ``*``."""
    metric = (data.get("holdout") or {}).get("metric", "holdout score")
    head = ["", "version", "status", "created_at", metric, "parent", "reason"]
    body = [["*" if r["current"] else "", r["version"], r["status"] or "-", r["created_at"] or "-",
             _score(r["holdout_score"]), r["parent"] or "-", r["reason"] or "-"] for r in rows(data)]
    widths = [max(len(row[i]) for row in [head, *body]) for i in range(len(head) - 1)]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row[:-1], widths, strict=True)) + "  " + row[-1]
             for row in [head, *body]]
    for alias, table in sorted((data.get("aliases") or {}).items()):
        lines.append(f"{alias}: " + ", ".join(f"{o} <- {e['model']} of {e['version']}"
                                              for o, e in sorted(table.items())))
    return "\n".join(line.rstrip() for line in lines)


def describe_version(data: dict[str, Any], name: str, root: str | Path) -> dict[str, Any]:
    """Everything ``auvid models show`` says about a version: its entry, whether it is current, its lineage
    chain (itself, parent, grandparent, ...) and the holdout it was scored on."""
    entry = require_version(data, name, root)
    return {**entry, "current": data.get("current") == name, "chain": lineage_chain(data, name),
            "holdout_definition": data.get("holdout")}


def format_version(info: dict[str, Any], root: str | Path) -> str:
    """The text form of :func:`describe_version`."""
    lineage = info.get("lineage") or {}
    holdout = info.get("holdout_definition") or {}
    metrics = info.get("metrics") or {}
    pad = "\n" + " " * 20

    def line(label: str, text: object) -> str:
        return f"  {label:<17} {text}"

    on = ", ".join(lineage.get("holdout") or holdout.get("trials") or []) or "-"
    better = "higher" if holdout.get("mode", "max") == "max" else "lower"
    out = [f"{info['version']}: {info.get('status')}" + (" (current)" if info["current"] else ""),
           line("created_at", info.get("created_at") or "-"),
           line("reason", info.get("reason") or "-"),
           line("holdout score", f"{_score(info.get('holdout_score'))} ({holdout.get('metric', '?')}, {better} is "
                                 f"better, on {on})"),
           line("lineage", " <- ".join(info["chain"]) + ("" if info.get("parent") else " (first model)")),
           line("metrics", ", ".join(f"{k} {v if isinstance(v, str) else _score(v)}"
                                     for k, v in sorted(metrics.items())) or "-")]
    logs = lineage.get("new_logs") or []
    out.append(line("new logs", len(logs)) + "".join(f"{pad}{e.get('name')}  sha256 {str(e.get('sha256'))[:12]}"
                                                     for e in logs))
    out.append(line("trials", ", ".join(lineage.get("trials") or []) or "-"))
    for key in ("vehicle_hash", "params_hash", "package_version"):
        out.append(line(key, lineage.get(key) or "-"))
    quarantined = lineage.get("quarantined") or []
    out.append(line("quarantined", len(quarantined)) + "".join(
        f"{pad}{q.get('file') or q.get('model')}: {q.get('reason')}" for q in quarantined))
    for event in info.get("events") or []:
        out.append(line(str(event.get("action")), f"{event.get('at')}: {event.get('from') or '-'} -> "
                                                  f"{event.get('to')} ({event.get('note')})"))
    out.append(line("models", Path(root) / "models" / info["version"]))
    return "\n".join(out)
