"""Read a config file as YAML, refusing what ``yaml.safe_load`` lets through or turns into a traceback.

- the bytes must be UTF-8 (a UTF-8 byte-order mark is fine): a latin-1 or UTF-16 file is a ConfigError
  naming the byte, its offset and line;
- a key given twice in one mapping is an error naming the key path and both lines (``safe_load`` keeps the
  last silently); keys merged in with ``<<: *anchor`` may be overridden, as YAML intends;
- nesting deeper than the parser's recursion allows, and aliases that expand to more than
  :data:`MAX_VALUES` values (or refer to themselves), are ConfigErrors, not RecursionError or a hang.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from pipeline.errors import ConfigError

#: Most values (scalars, lists, mappings) a config may expand to, aliases counted each time they are used.
#: A vehicle config holds a few hundred; the cap stops "billion laughs" alias bombs before validation.
MAX_VALUES = 1_000_000

_MERGE_TAG = "tag:yaml.org,2002:merge"

#: libyaml's parser where PyYAML was built with it (its wheels are): far cheaper than the pure-Python one, whose
#: parsing is most of loading a config (docs/benchmarks.md); the resolver and constructor are PyYAML's either way.
#: libyaml stops nesting at 1,000 levels itself. tests/config/test_config_refuses.py runs every unreadable-file case
#: through both parsers.
_Loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def _decode(raw: bytes, path: Path) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw[: err.start].count(b"\n") + 1
        if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
            what = "UTF-16 (it starts with a UTF-16 byte-order mark)"
        else:
            what = f"not UTF-8: byte 0x{raw[err.start]:02x} at offset {err.start} (line {line})"
        raise ConfigError(f"config files are UTF-8 text; this file is {what}: save it as UTF-8", file=path) from None


def _yaml_message(err: yaml.YAMLError, text: str) -> str:
    """What the parser refused and where (line, column), without its "<unicode string>" placeholder for the file."""
    if isinstance(err, yaml.reader.ReaderError):
        if _Loader is yaml.SafeLoader:  # the pure-Python reader counts the position in characters
            line = text[: err.position].count("\n") + 1
        else:  # libyaml in UTF-8 bytes
            line = text.encode("utf-8")[: err.position].count(b"\n") + 1
        return (f"not valid YAML at line {line}: character #x{err.character:04x} is not allowed (a control or "
                "special character)")
    mark = getattr(err, "problem_mark", None)
    if isinstance(err, yaml.MarkedYAMLError) and mark is not None and "maximum nesting depth" in (err.problem or ""):
        return (f"nested too deeply for the YAML parser (it gave up at line {mark.line + 1}, column "
                f"{mark.column + 1}); a config is a few levels deep")
    if isinstance(err, yaml.MarkedYAMLError) and mark is not None:
        what = ", ".join(x for x in (err.context, err.problem) if x)
        return f"not valid YAML at line {mark.line + 1}, column {mark.column + 1}: {what}"
    return f"not valid YAML: {err}"


def _key_text(node: yaml.Node) -> str:
    return str(node.value) if isinstance(node, yaml.ScalarNode) else f"<{node.id} at line {node.start_mark.line + 1}>"


def _check_duplicate_keys(root: yaml.Node, path: Path) -> None:
    """Walk the composed node tree (iteratively: no recursion limit) and refuse a key given twice."""
    stack: list[tuple[yaml.Node, str]] = [(root, "")]
    seen_nodes: set[int] = set()
    while stack:
        node, where = stack.pop()
        if id(node) in seen_nodes:  # an alias: the anchored node was checked once
            continue
        seen_nodes.add(id(node))
        if isinstance(node, yaml.MappingNode):
            first: dict[tuple[str, str], yaml.Node] = {}
            for key_node, value_node in node.value:
                if key_node.tag == _MERGE_TAG:
                    stack.append((value_node, where))
                    continue
                key = _key_text(key_node)
                dotted = f"{where}.{key}" if where else key
                ident = (key_node.tag, key)
                if ident in first:
                    raise ConfigError(f"duplicate key {key!r} at line {key_node.start_mark.line + 1} (first at line "
                                      f"{first[ident].start_mark.line + 1}): YAML would keep only the last; give "
                                      "it once", file=path, field=dotted)
                first[ident] = key_node
                stack.append((value_node, dotted))
        elif isinstance(node, yaml.SequenceNode):
            stack.extend((item, f"{where}.{i}" if where else str(i)) for i, item in enumerate(node.value))


def _check_size(data: Any, path: Path) -> None:
    """Count values as a validator will see them (aliases expanded); stop at :data:`MAX_VALUES`."""
    stack = [data]
    count = 0
    while stack:
        value = stack.pop()
        count += 1
        if count > MAX_VALUES:
            raise ConfigError(f"expands to more than {MAX_VALUES:,} values (aliases that repeat or refer to "
                              "themselves); a config is far smaller", file=path)
        if isinstance(value, dict):
            stack.extend(value.keys())
            stack.extend(value.values())
        elif isinstance(value, list):
            stack.extend(value)


def load_yaml(path: str | Path) -> Any:
    """The YAML document in ``path``, as Python values; a ConfigError names the file (and the line) otherwise."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise ConfigError("config file not found", file=path) from None
    except IsADirectoryError:
        raise ConfigError("expected a YAML file, found a directory", file=path) from None
    except OSError as err:
        raise ConfigError(f"cannot read the config file: {err.strerror or err}", file=path) from None
    return parse_yaml(raw, path)


def parse_yaml(raw: bytes, path: str | Path) -> Any:
    """:func:`load_yaml` of bytes already read from ``path`` (named in the errors)."""
    path = Path(path)
    text = _decode(raw, path)
    try:
        loader = _Loader(text)  # its reader refuses control characters here already
    except yaml.YAMLError as err:
        raise ConfigError(_yaml_message(err, text), file=path) from None
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _check_duplicate_keys(node, path)
        data = loader.construct_document(node)
    except yaml.YAMLError as err:
        raise ConfigError(_yaml_message(err, text), file=path) from None
    except RecursionError:  # the pure-Python parser (libyaml stops at 1,000 levels with a YAMLError above)
        mark = loader.get_mark() if hasattr(loader, "get_mark") else None
        where = f" (it gave up at line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        raise ConfigError(f"nested too deeply for the YAML parser{where}; a config is a few levels deep",
                          file=path) from None
    finally:
        loader.dispose()
    _check_size(data, path)
    return data
