"""Property: the fast columnar path and per-message decoding give bit-identical columns for generated types.

Hypothesis draws a message definition (primitives of every type, strings, fixed arrays, sequences of
primitives, strings and structs, nested structs, a JointState-like name list) and messages of it; rosbags
serializes them (CDR in both byte orders, ROS 1); both decoding paths must agree on every scalar leaf, on
indices past a sequence's end and on selections by name, bit for bit.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from pipeline.io.base import Batcher, Rows, TopicInfo
from pipeline.io.cdr import TopicDecoder
from pipeline.io.fields import TypeRegistry, resolve

PRIMS = ["bool", "byte", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32",
         "float64"]
NP = {"bool": np.bool_, "byte": np.int8, "int8": np.int8, "uint8": np.uint8, "int16": np.int16,
      "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32, "int64": np.int64, "uint64": np.uint64,
      "float32": np.float32, "float64": np.float64}
KINDS = ["prim", "string", "array", "seq", "strseq", "inner", "innerseq"]
FIELD = st.tuples(st.sampled_from(KINDS), st.sampled_from(PRIMS))


def _definition(fields: list[tuple[str, str]], inner: list[str], header: bool) -> tuple[str, str, list[str]]:
    """(top .msg text, inner .msg text, requested paths)."""
    inner_text = "\n".join(f"{t} {chr(97 + i)}" for i, t in enumerate(inner[:1])) + "\nstring tag\n" + \
        "\n".join(f"{t} {chr(98 + i)}" for i, t in enumerate(inner[1:]))
    lines, paths = [], []
    if header:
        lines.append("std_msgs/Header header")
    for i, (kind, prim) in enumerate(fields):
        name = f"f{i}"
        if kind == "prim":
            lines.append(f"{prim} {name}")
            paths.append(name)
        elif kind == "string":
            lines.append(f"string {name}")
        elif kind == "array":
            lines.append(f"{prim}[3] {name}")
            paths += [f"{name}[0]", f"{name}[2]"]
        elif kind == "seq":
            lines.append(f"{prim}[] {name}")
            paths += [f"{name}[0]", f"{name}[1]"]
        elif kind == "strseq":
            lines.append(f"string[] {name}")
        elif kind == "inner":
            lines.append(f"prop_msgs/Inner {name}")
            paths += [f"{name}.a"] + [f"{name}.{chr(98 + k)}" for k in range(len(inner) - 1)]
        else:
            lines.append(f"prop_msgs/Inner[] {name}")
            paths += [f"{name}[0].a", f"{name}[1].a"]
    lines += ["string[] names", "float64[] values"]
    paths += ["values[names=th1]", "values[names=th2]", "values[0]"]
    return "\n".join(lines) + "\n", inner_text + "\n", paths


def _value(rng: np.random.Generator, prim: str) -> Any:
    if prim == "bool":
        return bool(rng.integers(0, 2))
    if prim.startswith("float"):
        return float(NP[prim](rng.normal() * 1e3))
    info = np.iinfo(NP[prim])
    return int(rng.integers(info.min, info.max, endpoint=True, dtype=np.int64 if info.min < 0 else np.uint64))


def _array(rng: np.random.Generator, prim: str, n: int) -> np.ndarray:
    return np.array([_value(rng, prim) for _ in range(n)], dtype=NP[prim])


def _text(rng: np.random.Generator) -> str:
    return "".join(rng.choice(list("abcxyzé_"), size=int(rng.integers(0, 7))))


def _messages(store: Any, fields: list[tuple[str, str]], inner: list[str], header: bool, ros1: bool, n: int,
              seed: int, uniform: bool = False) -> list[Any]:
    """Messages with random values; ``uniform``: all with the same lengths, strings and names (one layout)."""
    rng = np.random.default_rng(seed)
    srng = rng
    types = store.types
    top, inn = types["prop_msgs/msg/Top"], types["prop_msgs/msg/Inner"]

    def make_inner() -> Any:
        kw = {"a": _value(rng, inner[0]), "tag": _text(srng)}
        kw.update({chr(98 + k): _value(rng, t) for k, t in enumerate(inner[1:])})
        return inn(**kw)

    out = []
    for i in range(n):
        if uniform:
            srng = np.random.default_rng(seed + 1)
        kw: dict[str, Any] = {}
        if header:
            stamp = types["builtin_interfaces/msg/Time"](sec=int(rng.integers(0, 2**31)),
                                                         nanosec=int(rng.integers(0, 10**9)))
            hkw = {"seq": i} if ros1 else {}
            kw["header"] = types["std_msgs/msg/Header"](**hkw, stamp=stamp, frame_id=_text(srng))
        for j, (kind, prim) in enumerate(fields):
            name = f"f{j}"
            if kind == "prim":
                kw[name] = _value(rng, prim)
            elif kind == "string":
                kw[name] = _text(srng)
            elif kind == "array":
                kw[name] = _array(rng, prim, 3)
            elif kind == "seq":
                kw[name] = _array(rng, prim, int(srng.integers(0, 4)))
            elif kind == "strseq":
                kw[name] = [_text(srng) for _ in range(int(srng.integers(0, 3)))]
            elif kind == "inner":
                kw[name] = make_inner()
            else:
                kw[name] = [make_inner() for _ in range(int(srng.integers(0, 3)))]
        names = list(srng.permutation(["th1", "th2", "th3"])[:int(srng.integers(0, 4))])
        kw["names"] = [str(x) for x in names]
        kw["values"] = rng.normal(size=int(srng.integers(0, 4)))
        out.append(top(**kw))
    return out


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(fields=st.lists(FIELD, min_size=0, max_size=6), inner=st.lists(st.sampled_from(PRIMS), min_size=1, max_size=3),
       header=st.booleans(), encoding=st.sampled_from(["cdr-le", "cdr-be", "ros1"]),
       n=st.integers(min_value=0, max_value=12), seed=st.integers(min_value=0, max_value=2**32 - 2),
       uniform=st.booleans())
def test_fast_equals_per_message(fields: list[tuple[str, str]], inner: list[str], header: bool, encoding: str,
                                 n: int, seed: int, uniform: bool) -> None:
    ros1 = encoding == "ros1"
    top_text, inner_text, paths = _definition(fields, inner, header)
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.LATEST)
    if ros1:
        top_text = top_text.replace("std_msgs/Header", "Header")
    store.register(get_types_from_msg(inner_text, "prop_msgs/msg/Inner"))
    store.register(get_types_from_msg(top_text, "prop_msgs/msg/Top"))
    msgs = _messages(store, fields, inner, header, ros1, n, seed, uniform)
    if ros1:
        raw = [bytes(store.serialize_ros1(m, "prop_msgs/msg/Top")) for m in msgs]
    else:
        raw = [bytes(store.serialize_cdr(m, "prop_msgs/msg/Top", little_endian=encoding == "cdr-le")) for m in msgs]

    registry = TypeRegistry(ros1=ros1)
    registry.add("prop_msgs/msg/Inner", "ros1msg" if ros1 else "ros2msg", inner_text)
    header_def = "=" * 80 + "\nMSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n"
    registry.add("prop_msgs/msg/Top", "ros1msg" if ros1 else "ros2msg",
                 top_text + (header_def if ros1 and header else ""))
    assert registry.ensure("prop_msgs/msg/Top") is None
    info = TopicInfo("/t", "prop_msgs/msg/Top", n, None, None, header)
    plans = [resolve(registry, "prop_msgs/msg/Top", p, file=None, topic="/t") for p in paths]  # type: ignore[arg-type]
    batcher = Batcher()
    for i, payload in enumerate(raw):
        batcher.add("/t", i, b"\x00" * (i % 3) + payload)  # misaligned starts in the shared buffer
    batch = batcher.flush()
    out = {}
    for fast in (True, False):
        dec = TopicDecoder(registry, info, plans, ros1=ros1, allow_fast=fast)
        if batch is not None:
            rows = batch.rows["/t"]
            rows.starts += np.arange(n) % 3
            rows.lengths -= np.arange(n) % 3
            # Fed as up to three batches, so that a layout the fast path keeps from one batch to the next is
            # reused (or rightly not) on messages it was not worked out on.
            cuts = sorted({0, n, *(int(c) for c in np.random.default_rng(seed).integers(0, n + 1, 2))})
            for lo, hi in zip(cuts[:-1], cuts[1:], strict=False):
                dec.feed(batch.buf, Rows(rows.starts[lo:hi], rows.lengths[lo:hi], rows.log_ns[lo:hi]))
            rows.starts -= np.arange(n) % 3
            rows.lengths += np.arange(n) % 3
        out[fast] = dec.result(n)
    a, b = out[True], out[False]
    assert a.path == "fast"
    assert b.path == "per-message"
    for p in paths:
        assert a.columns[p].tobytes() == b.columns[p].tobytes(), p
    if header:
        assert a.header_ns.tobytes() == b.header_ns.tobytes()


def test_layout_of_one_batch_is_not_reused_on_messages_that_differ_in_their_keys() -> None:
    """JointState messages of equal size whose joint names come in another order: the fast path keeps the
    layout of a batch for the next, and must see that the selected joint now lies elsewhere."""
    store = get_typestore(Stores.LATEST)
    js = store.types["sensor_msgs/msg/JointState"]
    header = store.types["std_msgs/msg/Header"]
    stamp = store.types["builtin_interfaces/msg/Time"]

    def msg(names: list[str], vel: list[float], sec: int) -> bytes:
        m = js(header=header(stamp=stamp(sec=sec, nanosec=0), frame_id="t"), name=names,
               position=np.zeros(2), velocity=np.array(vel), effort=np.zeros(2))
        return bytes(store.serialize_cdr(m, "sensor_msgs/msg/JointState"))

    first = [msg(["a", "bbbbb"], [1.0 + i, -1.0], i) for i in range(3)]
    second = [msg(["aaaaa", "a"], [-2.0, 2.0 + i], 10 + i) for i in range(3)]  # "a" is now the second joint
    assert {len(m) for m in first} == {len(m) for m in second}
    registry = TypeRegistry(ros1=False)
    info = TopicInfo("/js", "sensor_msgs/msg/JointState", 6, None, None, True)
    plans = [resolve(registry, "sensor_msgs/msg/JointState", "velocity[name=a]", file=None, topic="/js")]
    dec = TopicDecoder(registry, info, plans, ros1=False)
    for part in (first, second):
        batcher = Batcher()
        for i, payload in enumerate(part):
            batcher.add("/js", i, payload)
        batch = batcher.flush()
        assert batch is not None
        dec.feed(batch.buf, batch.rows["/js"])
    got = dec.result(6)
    assert got.path == "fast"
    assert got.columns["velocity[name=a]"].tolist() == [1.0, 2.0, 3.0, 2.0, 3.0, 4.0]
    assert got.header_ns.tolist() == [i * 1_000_000_000 for i in (0, 1, 2, 10, 11, 12)]
