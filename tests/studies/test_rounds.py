"""Coroutines that decide in rounds (pipeline.rounds): the same decisions inline, on a forked pool and with many
coroutines at once; a task's exception reaches its own coroutine; each round's tasks are recorded after the round
before them, so that a run's critical path is one coroutine's rounds (bench/span.py)."""

from __future__ import annotations

import importlib.util
import json
import os
import time
from pathlib import Path

import numpy as np
import pytest

from pipeline import parallel
from pipeline.rounds import drive, gather, run_inline

ROOT = Path(__file__).resolve().parents[2]


def _noisy_square(x: float, seed: int) -> float:
    """A task whose answer the coroutine needs to go on: x^2 plus a seeded perturbation."""
    return x * x + float(np.random.default_rng(seed).normal(0.0, 1e-3))


def _descent(start: float, rounds: int, width: int):  # noqa: ANN202  (a coroutine of pipeline.rounds)
    """A toy search: each round scores ``width`` points around the best so far and moves to the lowest."""
    x, path = start, []
    for r in range(rounds):
        points = [x + (k - width // 2) * 0.5 ** r for k in range(width)]
        scores = yield [(_noisy_square, (p, 1000 * r + k)) for k, p in enumerate(points)]
        x = points[int(np.argmin(scores))]
        path.append(x)
    return path


def _failing(x: float) -> float:
    raise ValueError(f"no score for {x}")


def _recovers():  # noqa: ANN202
    """Asks for a task that fails, handles the failure, asks again."""
    try:
        yield [(_failing, (1.0,)), (_noisy_square, (2.0, 0))]
    except ValueError as err:
        got = str(err)
    again = yield [(_noisy_square, (3.0, 0))]
    return got, again


def test_many_coroutines_on_a_pool_decide_as_each_would_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    starts = [3.0, -2.0, 0.7, 3.5]
    alone = [run_inline(_descent(s, 6, 5)) for s in starts]
    assert all(abs(path[-1]) < 0.1 for path in alone)  # the toy search works: each ends near 0
    inline = drive([_descent(s, 6, 5) for s in starts], jobs=1)
    with parallel.parallel_backend(None):  # the run's forked pool, as a stage has it
        pooled = drive([_descent(s, 6, 5) for s in starts], jobs=2)
    assert inline == alone and pooled == alone


def test_gathered_coroutines_decide_as_each_alone_in_the_rounds_of_the_longest(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    alone = [run_inline(_descent(s, n, 3)) for s, n in ((2.0, 5), (-1.0, 2), (0.5, 3))]
    trace = tmp_path / "trace.jsonl"
    monkeypatch.setenv(parallel.ENV_TASK_TRACE, str(trace))
    together = run_inline(gather([_descent(s, n, 3) for s, n in ((2.0, 5), (-1.0, 2), (0.5, 3))]), "tune", "g")
    assert together == alone
    rounds = [json.loads(line)["task"].split(" #")[0] for line in trace.read_text().splitlines()]
    # 5 rounds (the longest one's), not 5 + 2 + 3; the first holds all three's 9 tasks
    assert sorted(set(rounds)) == [f"g r{k}" for k in range(5)] and rounds.count("g r0") == 9


def test_a_task_exception_is_thrown_into_its_own_coroutine() -> None:
    with parallel.parallel_backend(None):
        pooled = drive([_recovers(), _descent(1.0, 2, 3)], jobs=2)
    inline = drive([_recovers(), _descent(1.0, 2, 3)], jobs=1)
    for got in (pooled, inline):
        assert got[0][0] == "no score for 1.0" and got[0][1] == [pytest.approx(9.0, abs=0.01)]
        assert got[1] == inline[1]

    def unhandled():  # noqa: ANN202
        yield [(_failing, (7.0,))]

    with parallel.parallel_backend(None), pytest.raises(ValueError, match="no score for 7.0"):
        drive([unhandled(), _descent(1.0, 2, 3)], jobs=2)


def _fails_then_asks_again():  # noqa: ANN202
    try:
        yield [(_failing, (1.0,)), (_noisy_square, (2.0, 0))]
    except ValueError:
        pass
    return (yield [(_noisy_square, (3.0, 0))])


def test_a_round_ended_by_an_exception_ignores_its_other_tasks_as_they_end() -> None:
    # the failing task and its round's other task often end in the same wait: the other must not be taken for a
    # task of the next round (it was: a KeyError, one run in a few dozen)
    with parallel.parallel_backend(None):
        for _ in range(100):
            assert drive([_fails_then_asks_again()], jobs=2) == [[pytest.approx(9.0, abs=0.01)]]


def _load_span() -> object:
    spec = importlib.util.spec_from_file_location("bench_span", ROOT / "bench" / "span.py")
    module = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(module)
    return module


def test_rounds_are_recorded_with_the_round_before_and_the_span_is_the_longest_chain(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    trace = tmp_path / "trace.jsonl"
    monkeypatch.setenv(parallel.ENV_TASK_TRACE, str(trace))
    drive([_descent(1.0, 3, 4), _descent(2.0, 2, 2)], jobs=1, stage="tune", labels=["a", "b"])
    records = [json.loads(line) for line in trace.read_text().splitlines()]
    assert [r["task"] for r in records[:5]] == ["a r0 #0", "a r0 #1", "a r0 #2", "a r0 #3", "a r1 #0"]
    assert records[0]["deps"] == [] and records[4]["deps"] == ["a r0"] and records[-1]["deps"] == ["b r0"]
    assert len(records) == 3 * 4 + 2 * 2 and {r["pid"] for r in records} == {os.getpid()}

    span = _load_span()
    # known walls: chain a has rounds of 1+2, 4, 1 s (slowest 2, 4, 1: 7 s); chain b 3 s then 3 s (6 s); the
    # train-like tasks without dependencies: the longest, 5 s
    made = [{"task": f"a r{k} #{j}", "wall_s": w, "deps": [f"a r{k - 1}"] if k else []}
            for k, walls in enumerate([[1.0, 2.0], [4.0], [1.0]]) for j, w in enumerate(walls)]
    made += [{"task": f"b r{k} #0", "wall_s": 3.0, "deps": [f"b r{k - 1}"] if k else []} for k in range(2)]
    assert span.longest_path(made) == pytest.approx(7.0)
    assert span.longest_path([{"task": f"fold {k}", "wall_s": w, "deps": []} for k, w in enumerate([2, 5, 1])]) == 5
    t0 = time.time()
    shape = span.span_of([{"stage": "run", "task": "tune", "wall_s": 20.0, "start": t0},
                          *({"stage": "tune", **r} for r in made)])
    # serial part: 20 s less the tasks' 14 s; span 6 + 7
    assert shape["span_s"] == pytest.approx(13.0) and shape["work_over_span"] == pytest.approx(20.0 / 13.0)


def test_a_round_goes_to_a_cluster_in_groups_of_about_two_per_worker_thread() -> None:
    """A Dask task costs a few ms of scheduling, more than many of a search's fits: on a cluster a round's tasks
    travel in groups (about two per worker thread, in order), locally one by one; every task is in one group."""
    from pipeline.rounds import _executor

    local = _executor(2)
    local.client = None
    assert local.groups(5) == [[0], [1], [2], [3], [4]]
    cluster = _executor(-1)
    cluster.client, cluster.threads = object(), 2
    assert cluster.groups(10) == [[0, 1, 2], [3, 4, 5], [6, 7, 8], [9]]
    assert cluster.groups(3) == [[0], [1], [2]] and cluster.groups(0) == []
