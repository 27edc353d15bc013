"""User message definitions: directories of ``.msg`` / ``.idl`` files for the types a log does not embed.

ROS 2 sqlite3 bags recorded before Iron carry no message definitions, a recorder that does not know a type writes
an empty one, and an MCAP file may lack a schema. Types such as ``mavros_msgs/msg/OverrideRCIn`` or the px4_msgs
are then undecodable unless the user gives their definitions: the vehicle config's ``message_definitions`` lists
directories, searched recursively.

- ``<dir>/<pkg>/msg/Foo.msg`` (a ROS package tree, or a ``share/`` directory of an install) gives ``pkg/msg/Foo``;
  a ``.msg`` file in a directory not called ``msg`` takes that directory's name as its package.
- ``.idl`` files name their types themselves (``module pkg { module msg { struct Foo ...``).

Parsing is rosbags' (:func:`rosbags.typesys.get_types_from_msg`, :func:`~rosbags.typesys.get_types_from_idl`).
A file that does not parse makes only its own type(s) undecodable (the error names the file), as a broken
embedded definition does. Definitions embedded in a log win over the user's; the user's win over the ROS 2
standard types. Parsed files are cached by path, size and modification time, so a batch of trials parses each once.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rosbags.typesys import get_types_from_idl, get_types_from_msg

log = logging.getLogger(__name__)

CONFIG_KEY = "message_definitions"
SUFFIXES = (".msg", ".idl")

_CACHE: dict[Path, tuple[tuple[int, int], dict[str, Any], str | None]] = {}


@dataclass(frozen=True)
class UserTypes:
    """The types parsed from the user's definition directories."""

    dirs: tuple[Path, ...] = ()
    types: dict[str, Any] = field(default_factory=dict)   # type name -> rosbags field definitions
    origin: dict[str, Path] = field(default_factory=dict)  # type name -> the file it came from
    errors: dict[str, str] = field(default_factory=dict)   # type name -> why its file does not parse

    def missing(self, msgtype: str) -> str:
        """Why ``msgtype`` has no definition, with the config key to set."""
        if msgtype in self.errors:
            return f"the user definition of {msgtype} does not parse: {self.errors[msgtype]}"
        pkg, _, name = msgtype.rpartition("/")
        pkg = pkg.split("/")[0]
        where = (f"none of the directories under `{CONFIG_KEY}` in the vehicle config "
                 f"({[str(d) for d in self.dirs]}) holds it" if self.dirs else
                 f"`{CONFIG_KEY}` is not set in the vehicle config")
        broken = f" ({len(self.errors)} file(s) there do not parse: {sorted(self.errors.values())[:3]})" \
            if self.errors else ""
        return (f"no definition of {msgtype}: the log embeds none, it is not a ROS 2 standard type, and "
                f"{where}{broken}; list a directory holding {pkg}/msg/{name}.msg (or an .idl file; a ROS package "
                f"tree works) under `{CONFIG_KEY}`")


def msgtype_of(path: Path) -> str:
    """The type a ``.msg`` file defines, from its place: ``<pkg>/msg/Foo.msg`` -> ``pkg/msg/Foo``."""
    parent = path.parent
    pkg = parent.parent.name if parent.name == "msg" else parent.name
    return f"{pkg}/msg/{path.stem}"


def _parse(path: Path) -> tuple[dict[str, Any], str | None]:
    """The types of one file (cached by size and mtime), or the parse error."""
    st = path.stat()
    key = (st.st_size, st.st_mtime_ns)
    hit = _CACHE.get(path)
    if hit is not None and hit[0] == key:
        return hit[1], hit[2]
    text = path.read_text(encoding="utf-8")
    try:
        if path.suffix == ".idl":
            typs, err = dict(get_types_from_idl(text)), None
        else:
            typs, err = dict(get_types_from_msg(text, msgtype_of(path))), None
    except Exception as exc:  # noqa: BLE001 - any parse failure makes just this file's types undecodable
        typs, err = {}, f"{path}: {type(exc).__name__}: {exc}"
    _CACHE[path] = (key, typs, err)
    return typs, err


def load_user_types(dirs: Sequence[str | Path]) -> UserTypes:
    """Parse every ``.msg`` / ``.idl`` file under ``dirs`` (the first directory listed wins a duplicate type).

    A directory that does not exist raises FileNotFoundError (the caller names the config key).
    """
    out = UserTypes(dirs=tuple(Path(d) for d in dirs))
    for directory in out.dirs:
        if not directory.is_dir():
            raise FileNotFoundError(f"message definition directory {str(directory)!r} does not exist")
        files = sorted(p for p in directory.rglob("*") if p.suffix in SUFFIXES and p.is_file()
                       and not any(part.startswith(".") for part in p.relative_to(directory).parts))
        for path in files:
            typs, err = _parse(path)
            if err is not None:
                name = msgtype_of(path) if path.suffix == ".msg" else f"(types of {path.name})"
                out.errors.setdefault(name, err)
                log.warning("user message definition does not parse: %s", err)
            for name, fielddefs in typs.items():
                if name in out.types:
                    if out.types[name] != fielddefs:
                        log.warning("%s is defined twice with different fields: %s is used, %s is not", name,
                                    out.origin[name], path)
                    continue
                out.types[name] = fielddefs
                out.origin[name] = path
    log.debug("user message definitions: %d type(s) from %s", len(out.types), [str(d) for d in out.dirs])
    return out
