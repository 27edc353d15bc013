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

Files are read as UTF-8, as the ROS tools read them: a file in another encoding (a latin-1 comment) makes its
types undecodable, naming the file and the byte. The walk is bounded: the file system's root and the kernel's
pseudo file systems (``/proc``, ``/sys``, ``/dev``) are refused, symbolic links to directories are not followed,
and a tree of more than :data:`MAX_ENTRIES` entries (a whole disk given by mistake) or a definition file larger
than :data:`MAX_FILE_BYTES` is refused with the directory or file named.
"""

from __future__ import annotations

import logging
import os
import stat
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rosbags.typesys import get_types_from_idl, get_types_from_msg

from pipeline.errors import ConfigError

log = logging.getLogger(__name__)

CONFIG_KEY = "message_definitions"
SUFFIXES = (".msg", ".idl")

#: Most entries (files and directories) walked under one definition directory: a ROS 2 desktop install's
#: ``share/`` holds a few ten thousand; more is a whole disk given by mistake.
MAX_ENTRIES = 200_000
#: Largest .msg / .idl file read: the largest ROS 2 definitions are a few kB.
MAX_FILE_BYTES = 1 << 20
_PSEUDO = (Path("/proc"), Path("/sys"), Path("/dev"))

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
    try:
        if st.st_size > MAX_FILE_BYTES:
            raise ValueError(f"{st.st_size} bytes, more than the {MAX_FILE_BYTES >> 20} MiB a definition can be")
        with open(path, "rb") as handle:
            data = handle.read(MAX_FILE_BYTES + 1)
        text = _utf8(data)
        if path.suffix == ".idl":
            typs, err = dict(get_types_from_idl(text)), None
        else:
            typs, err = dict(get_types_from_msg(text, msgtype_of(path))), None
    except Exception as exc:  # noqa: BLE001 - any parse failure makes just this file's types undecodable
        typs, err = {}, f"{path}: {type(exc).__name__}: {exc}"
    _CACHE[path] = (key, typs, err)
    return typs, err


def _utf8(data: bytes) -> str:
    """The file's text; a ValueError naming the byte and line where it is not UTF-8 (as rosidl reads it)."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        line = data.count(b"\n", 0, err.start) + 1
        raise ValueError(f"not UTF-8 text: byte 0x{data[err.start]:02x} at line {line} (ROS tools read .msg and "
                         ".idl files as UTF-8; save it as UTF-8)") from None


def _check_directory(directory: Path) -> None:
    """Refuse the root and the kernel's pseudo file systems: no message definition lives there."""
    real = directory.resolve()
    if real == Path(real.anchor):
        raise ConfigError(f"message definition directory {str(directory)!r} is the file system's root; give the "
                          "directory holding the .msg / .idl packages", field=CONFIG_KEY)
    if any(real == p or p in real.parents for p in _PSEUDO):
        raise ConfigError(f"message definition directory {str(directory)!r} is on a kernel pseudo file system "
                          f"({real}); give the directory holding the .msg / .idl packages", field=CONFIG_KEY)


def _definition_files(directory: Path) -> Iterator[Path]:
    """The .msg / .idl files under ``directory`` (hidden entries skipped, directory links not followed), at most
    MAX_ENTRIES entries walked."""
    walked = 0
    stack = [directory]
    while stack:
        current = stack.pop()
        try:
            with os.scandir(current) as entries:
                found = sorted(entries, key=lambda e: e.name)
        except OSError as err:  # unreadable or vanished: its types stay unknown, said in the log
            log.warning("message definitions: cannot list %s: %s", current, err)
            continue
        walked += len(found)
        if walked > MAX_ENTRIES:
            raise ConfigError(f"message definition directory {str(directory)!r} holds more than {MAX_ENTRIES} "
                              "entries: not a directory of message packages (a whole disk?); give the directory "
                              "holding the .msg / .idl packages", field=CONFIG_KEY)
        for entry in found:
            if entry.name.startswith("."):
                continue
            if entry.is_dir(follow_symlinks=False):
                stack.append(Path(entry.path))
            elif entry.name.endswith(SUFFIXES) and _regular(entry):
                yield Path(entry.path)


def _regular(entry: os.DirEntry[str]) -> bool:
    """A regular file, through a link (never a device or FIFO named ``.msg``, nor a dangling link)."""
    try:
        return stat.S_ISREG(entry.stat().st_mode)
    except OSError:
        return False


def load_user_types(dirs: Sequence[str | Path]) -> UserTypes:
    """Parse every ``.msg`` / ``.idl`` file under ``dirs`` (the first directory listed wins a duplicate type).

    A directory that does not exist raises FileNotFoundError (the caller names the config key); the root, a
    pseudo file system or a tree too large to be one of message packages a ConfigError.
    """
    out = UserTypes(dirs=tuple(Path(d) for d in dirs))
    for directory in out.dirs:
        if not directory.is_dir():
            raise FileNotFoundError(f"message definition directory {str(directory)!r} does not exist")
        _check_directory(directory)
        files = sorted(_definition_files(directory))
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
