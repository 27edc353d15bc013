"""Message types from the definitions embedded in a file, and field paths into those messages.

A field path names one scalar leaf: ``velocity.x``, ``orientation.w``, ``velocity[2]``, ``data`` or the
JointState-style selection ``velocity[name=th1]`` (the index of ``'th1'`` in the message's ``name`` list, then that
element of ``velocity``). :func:`resolve` checks a path against the message definition before anything is decoded;
:func:`extract` applies it to one deserialized message.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype
from rosbags.typesys.store import Typestore

from pipeline.errors import IngestError
from pipeline.io.msgdefs import UserTypes

log = logging.getLogger(__name__)

NUMERIC = {
    "bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
    "float32", "float64",
}
_SEGMENT = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[[^\]]*\])*)$")
_LATEST: dict[str, Any] | None = None


def normalize_msgtype(name: str) -> str:
    """``sensor_msgs/Imu`` -> ``sensor_msgs/msg/Imu``; names with an interface kind stay as they are."""
    parts = name.strip().split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return name.strip()


def _latest() -> dict[str, Any]:
    global _LATEST
    if _LATEST is None:
        _LATEST = dict(get_typestore(Stores.LATEST).fielddefs)
    return _LATEST


#: ``time`` and ``duration`` of ROS 1, as rosbags names them; the only standard types a ROS 1 bag takes from rosbags.
_BUILTIN_MSGS = {"builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
                 "builtin_interfaces/msg/Duration": "int32 sec\nuint32 nanosec\n"}


class _Definitions(dict):  # type: ignore[type-arg]
    """Type name -> rosbags field definitions: the file's and the user's (the dict's own entries) first, then
    the standard ROS 2 types, looked up only for a name that is not among them.

    The standard types come from rosbags' LATEST store, whose modules are slow to import: a log that
    embeds its definitions (MCAP, a ROS 2 bag from Iron on) never needs them, and a ROS 1 bag needs only ``time``
    and ``duration``, which are parsed here instead.
    """

    def __init__(self, *, ros1: bool) -> None:
        super().__init__()
        self.ros1 = ros1
        if ros1:
            for name, text in _BUILTIN_MSGS.items():
                self.update(get_types_from_msg(text, name))

    def _standard(self, key: str) -> Any:
        return None if self.ros1 else _latest().get(key)

    def __missing__(self, key: str) -> Any:
        found = self._standard(key)
        if found is None:
            raise KeyError(key)
        return found

    def __contains__(self, key: object) -> bool:
        return dict.__contains__(self, key) or (isinstance(key, str) and self._standard(key) is not None)

    def get(self, key: str, default: Any = None) -> Any:  # type: ignore[override]
        try:
            return self[key]
        except KeyError:
            return default


class TypeRegistry:
    """The types of one file: embedded definitions first, then the user's (``message_definitions`` in the vehicle
    config, :mod:`pipeline.io.msgdefs`), then (ROS 2 only) the standard ROS 2 types.

    Types are registered in a rosbags Typestore lazily, only the closure of the types a topic needs, so that a
    broken definition of one type never sinks another topic.
    """

    def __init__(self, *, ros1: bool, user: UserTypes | None = None) -> None:
        self.ros1 = ros1
        # ROS 1 bags embed every definition; only the builtin time and duration come from rosbags
        self.defs: dict[str, Any] = _Definitions(ros1=ros1)
        self.user = user if user is not None else UserTypes()
        self.defs.update(self.user.types)
        self.errors: dict[str, str] = {}
        self.store: Typestore = get_typestore(Stores.EMPTY)

    def add(self, msgtype: str, encoding: str, text: str) -> None:
        """Parse one embedded definition (``ros2msg``/``ros1msg``/``ros2idl``); remember errors per type.

        An empty ROS 2 definition (a recorder that did not know the type writes one) is no definition: the type
        keeps the user's or the standard one, or stays undefined. (In a ROS 1 bag it is an empty message.)
        """
        if not text.strip() and (msgtype in self.defs or encoding != "ros1msg"):
            return
        try:
            if "/srv/" in msgtype and encoding != "ros2idl":
                typs = _service_types(msgtype, text)
            elif encoding == "ros2idl":
                typs = get_types_from_idl(text)
            elif encoding in ("ros2msg", "ros1msg", "msg", ""):
                typs = get_types_from_msg(text, msgtype)
            else:
                self.errors[msgtype] = f"schema encoding {encoding!r} is not a ROS message definition"
                return
        except Exception as err:  # noqa: BLE001 - any parse failure makes just this type undecodable
            self.errors[msgtype] = f"cannot parse the embedded definition of {msgtype}: {err}"
            return
        self.defs.update(typs)

    def closure(self, msgtype: str) -> list[str]:
        seen: list[str] = []
        todo = [msgtype]
        while todo:
            name = todo.pop()
            if name in seen:
                continue
            if name not in self.defs:
                raise KeyError(name)
            seen.append(name)
            for _, (kind, detail) in self.defs[name][1]:
                sub = _subtype(kind, detail)
                if sub is not None:
                    todo.append(sub)
        return seen

    def ensure(self, msgtype: str) -> str | None:
        """Register ``msgtype`` and its dependencies; return why it cannot be decoded, or None."""
        if msgtype in self.errors:
            return self.errors[msgtype]
        if msgtype in self.store.fielddefs:
            return None
        try:
            names = self.closure(msgtype)
        except KeyError as err:
            self.errors[msgtype] = self.user.missing(err.args[0])
            return self.errors[msgtype]
        todo = {n: self.defs[n] for n in names if n not in self.store.fielddefs}
        try:
            self.store.register(todo)
        except Exception as err:  # noqa: BLE001
            self.errors[msgtype] = f"cannot register {msgtype}: {err}"
            return self.errors[msgtype]
        return None

    def has_header(self, msgtype: str) -> bool:
        fields = self.defs.get(msgtype, ((), []))[1]
        return bool(fields) and fields[0][1] == (Nodetype.NAME, "std_msgs/msg/Header")


def _service_types(msgtype: str, text: str) -> dict[str, Any]:
    """Types of a service event/request/response from the embedded ``.srv`` text (request --- response)."""
    pkg, _, name = msgtype.split("/", 2)
    base = name.removesuffix("_Event").removesuffix("_Request").removesuffix("_Response")
    main, sep, deps = text.partition("\n=====")
    deps = sep.lstrip("\n") + deps if sep else ""
    parts = re.split(r"^---[ \t]*$", main, maxsplit=1, flags=re.M)
    req, resp = parts[0], parts[1] if len(parts) > 1 else ""
    out: dict[str, Any] = {}
    for part, suffix in ((req, "_Request"), (resp, "_Response")):
        tmp = f"{pkg}/msg/{base}{suffix}"
        typs = get_types_from_msg(part + ("\n" + deps if deps else ""), tmp)
        out.update({k: v for k, v in typs.items() if k != tmp})
        out[f"{pkg}/srv/{base}{suffix}"] = typs[tmp]
    out[f"{pkg}/srv/{base}_Event"] = ([], [
        ("info", (Nodetype.NAME, "service_msgs/msg/ServiceEventInfo")),
        ("request", (Nodetype.SEQUENCE, ((Nodetype.NAME, f"{pkg}/srv/{base}_Request"), 1))),
        ("response", (Nodetype.SEQUENCE, ((Nodetype.NAME, f"{pkg}/srv/{base}_Response"), 1))),
    ])
    return out


def _subtype(kind: int, detail: Any) -> str | None:
    if kind == Nodetype.NAME:
        return str(detail)
    if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        return _subtype(detail[0][0], detail[0][1])
    return None


@dataclass(frozen=True)
class Step:
    kind: str            # "attr" | "index" | "select"
    name: str = ""       # attr: field name; select: key field (sibling list of strings)
    index: int = 0
    value: str = ""      # select: the key value


@dataclass(frozen=True)
class FieldPath:
    text: str
    steps: tuple[Step, ...]
    leaf: str            # base type of the leaf (float64, bool, ...)


def leaf_paths(defs: dict[str, Any], msgtype: str, prefix: str = "", depth: int = 0) -> list[str]:
    """Scalar leaf paths of a type, for error messages (arrays shown as ``name[i]``)."""
    out: list[str] = []
    for name, (kind, detail) in defs.get(msgtype, ((), []))[1]:
        path = f"{prefix}{name}"
        if kind == Nodetype.BASE:
            out.append(path)
        elif kind == Nodetype.NAME and depth < 4:
            out.extend(leaf_paths(defs, detail, path + ".", depth + 1))
        elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            out.append(f"{path}[i]")
    return out


def resolve(registry: TypeRegistry, msgtype: str, text: str, *, file: Path, topic: str) -> FieldPath:
    """Check ``text`` against the definition of ``msgtype``; raise IngestError listing the available fields."""
    defs = registry.defs

    def fail(why: str) -> IngestError:
        avail = leaf_paths(defs, msgtype)
        return IngestError(f"{why}; fields of {msgtype}: {avail[:60]}", file=file, topic=topic, field=text)

    steps: list[Step] = []
    cur_type = msgtype
    node: tuple[int, Any] | None = None
    for seg in text.split("."):
        m = _SEGMENT.match(seg.strip())
        if not m or cur_type is None:
            raise fail(f"cannot parse field path segment {seg!r}")
        fields = dict(defs[cur_type][1])
        name, brackets = m.group(1), m.group(2)
        if name not in fields:
            raise fail(f"{cur_type} has no field {name!r}")
        steps.append(Step("attr", name=name))
        node = fields[name]
        for sel in re.findall(r"\[([^\]]*)\]", brackets):
            if node[0] not in (Nodetype.ARRAY, Nodetype.SEQUENCE):
                raise fail(f"field {name!r} is not an array")
            sel = sel.strip()
            if "=" in sel:
                key, value = (s.strip() for s in sel.split("=", 1))
                knode = fields.get(key)
                if knode is None or knode[0] not in (Nodetype.ARRAY, Nodetype.SEQUENCE) or \
                        knode[1][0] != (Nodetype.BASE, ("string", 0)):
                    raise fail(f"selection [{sel}] needs a string list field {key!r} beside {name!r}")
                steps.append(Step("select", name=key, value=value.strip("'\"")))
            else:
                try:
                    idx = int(sel)
                except ValueError:
                    raise fail(f"bad index [{sel}]") from None
                if idx < 0 or (node[0] == Nodetype.ARRAY and idx >= node[1][1]):
                    raise fail(f"index [{idx}] out of range for {name!r}")
                steps.append(Step("index", index=idx))
            node = node[1][0]
        cur_type = node[1] if node[0] == Nodetype.NAME else None
    assert node is not None
    if node[0] != Nodetype.BASE or node[1][0] not in NUMERIC:
        what = node[1] if node[0] == Nodetype.NAME else node[1][0] if node[0] == Nodetype.BASE else "array"
        raise fail(f"field is {what!r}, not a numeric or bool scalar")
    return FieldPath(text, tuple(steps), node[1][0])


def extract(msg: object, fp: FieldPath) -> float:
    """The value of one field path in one deserialized message (NaN when an index or name is absent)."""
    obj: Any = msg
    parent: Any = msg
    for step in fp.steps:
        if step.kind == "attr":
            parent = obj
            obj = getattr(obj, step.name)
        elif step.kind == "index":
            if step.index >= len(obj):
                return float("nan")
            obj = obj[step.index]
        else:
            keys = list(getattr(parent, step.name))
            if step.value not in keys:
                return float("nan")
            idx = keys.index(step.value)
            if idx >= len(obj):
                return float("nan")
            obj = obj[idx]
    return float(obj)


def header_ns(msg: object) -> int:
    stamp = msg.header.stamp  # type: ignore[attr-defined]
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
