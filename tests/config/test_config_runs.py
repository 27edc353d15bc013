"""Generated configs that load run the example to the end (issue 36, item 3): a handful, from a seeded generator
(the same configs every time), each through ``auvid run --to derive`` on three tiny simulated trials under CPU,
memory and wall limits: refused with file and key, done, or done with quarantined inputs; never a traceback, a
hang, a memory error or an exit 0 with a nonsense result. ``bench/fuzz_configs.py --run`` runs hundreds."""

from __future__ import annotations

import copy
import json
import random
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from tests.config.runs import GOOD, classify, nonsense, raw_logs, run_config, run_plan
from tests.config.strategies import CSV_TRIAL, PARAMS, VEHICLE, outcome, random_edit, write

SEED = "suite-run-1"
PER_KIND = 3  # configs that load, per kind: ~3 s each


def _loading(kind: str, tmp: Path) -> list[tuple[dict[str, Any], list[str]]]:
    """The first ``PER_KIND`` generated configs of ``kind`` that load and whose edits act before the features stage
    (a model section's edit is the bench's, run to ``report``); the generator is seeded."""
    found = []
    for i in range(5000):
        doc, what = random_edit(PARAMS if kind == "params" else VEHICLE, random.Random(f"{SEED}:{kind}:{i}"))
        if run_plan(kind, doc, what)[2] == "derive" and outcome(kind, write(tmp / f"{kind}.yaml", doc))[0] == "loaded":
            found.append((doc, what))
            if len(found) == PER_KIND:
                return found
    raise AssertionError(f"fewer than {PER_KIND} generated {kind} configs load")


@pytest.fixture(scope="module")
def raw(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    return raw_logs(tmp_path_factory.mktemp("raw"), duration_s=20.0)


@pytest.mark.parametrize("kind", ["params", "vehicle"])
def test_generated_configs_that_load_run_to_derive_without_traceback_hang_or_nonsense(
        raw: list[Path], tmp_path: Path, kind: str) -> None:
    for i, (doc, what) in enumerate(_loading(kind, tmp_path)):
        result, detail, _ = run_config(kind, doc, what, raw, tmp_path / f"work{i}", to="derive",
                                       limits={"derive_wall_s": 60.0})
        assert result in GOOD, f"{kind} with {what}: {result}: {detail}"


def test_the_unedited_configs_run_ok(raw: list[Path], tmp_path: Path) -> None:
    """The base of the campaign runs to the end with nothing to say: an outcome in a generated case is the edit's.
    Every trial reaches the derived tables, the CSV trial (its streams and the tank table) included."""
    assert run_config("vehicle", copy.deepcopy(VEHICLE), [], raw, tmp_path / "w", to="derive")[:2] == ("ran-ok", "")
    data = tmp_path / "w" / "run" / "data"
    assert sorted(p.stem for p in (data / "derived").glob("*.parquet")) == ["trial01", "trial02", "trial03"]
    assert pq.read_table(data / "signals" / CSV_TRIAL / "tank.parquet").num_rows > 0


@pytest.mark.parametrize(("path", "value", "file"), [
    (("streams", "tank", "csv", "delimiter"), ";", "tank.csv"),
    (("streams", "tank", "csv", "encoding"), "utf-16", "tank.csv"),
    (("trials", CSV_TRIAL, "streams", "dvl", "csv", "skip_rows"), 3, "dvl.csv"),
])
def test_an_edit_of_a_csv_option_is_read_by_the_campaign(raw: list[Path], tmp_path: Path, path: tuple[str, ...],
                                                          value: Any, file: str) -> None:
    """The campaign's CSV trial is read with the edited options (with only MCAP trials, a CSV option was never
    read): a file they make unreadable quarantines that trial, naming the file, and the others go on."""
    doc = copy.deepcopy(VEHICLE)
    target = doc
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    result, detail, _ = run_config("vehicle", doc, [".".join(path) + f" = {value!r}"], raw, tmp_path / "w",
                                   to="ingest")
    assert result == "quarantine", detail
    entries = json.loads((tmp_path / "w" / "run" / "data" / "signals" / "quarantine.json").read_text())
    assert [e["trial"] for e in entries["quarantined"]] == [CSV_TRIAL]
    assert file in json.dumps(entries["quarantined"][0]), entries


def test_a_params_edit_in_a_model_section_runs_to_report_with_untouched_keys_made_cheap() -> None:
    doc = copy.deepcopy(PARAMS)
    doc["coupled"]["max_evals"] = 7
    params, _, last = run_plan("params", doc, ["coupled.max_evals = 7"])
    assert last == "report" and params["coupled"]["tuning"] == "split" and params["coupled"]["max_evals"] == 7
    assert params["decoupled"]["max_samples"] == 200 and doc["coupled"]["tuning"] == "nested"  # doc untouched
    del doc["coupled"]
    assert "coupled" not in run_plan("params", doc, ["drop coupled"])[0]  # a dropped section stays dropped
    assert run_plan("params", copy.deepcopy(PARAMS), ["sync.rate_hz = 5"])[2] == "derive"


# -- the classification itself, on outputs whose right answer is known ----------------------------------------
def _root(tmp_path: Path, column: str = "udot_mps2", value: float = 0.5, rows: int = 3) -> Path:
    root = tmp_path / "run"
    (root / "data" / "derived").mkdir(parents=True)
    pq.write_table(pa.table({"t_ns": np.arange(rows, dtype=np.int64), column: np.full(rows, value),
                             "u_meas_mps": np.full(rows, np.nan)}), root / "data" / "derived" / "trial01.parquet")
    return root


def test_a_non_finite_model_column_is_nonsense_and_a_measured_one_is_not(tmp_path: Path) -> None:
    assert nonsense(_root(tmp_path / "a"), "") == ""  # u_meas_mps: NaN where the DVL had no sample
    assert "udot_mps2 has 3 non-finite" in nonsense(_root(tmp_path / "b", value=np.nan), "")
    assert "tau_r_Nm" in nonsense(_root(tmp_path / "c", column="tau_r_Nm", value=np.inf), "")


def test_an_empty_result_is_nonsense_only_without_a_warning(tmp_path: Path) -> None:
    root = _root(tmp_path, rows=0)
    assert nonsense(root, "") == "no derived row and no warning"
    assert nonsense(root, "WARNING pipeline.sync: no segment of 5 s") == ""


def test_nan_in_an_output_json_is_nonsense_even_where_its_object_says_why(tmp_path: Path) -> None:
    root = _root(tmp_path)
    out = root / "data" / "evaluation" / "metrics.json"
    out.parent.mkdir(parents=True)
    out.write_text(json.dumps({"ls": {"u": {"final_r2": float("nan")}}}))
    assert nonsense(root, "") == "data/evaluation/metrics.json: ls.u.final_r2 is not finite"
    out.write_text(json.dumps({"p": {"bias_radps": float("nan"), "reason": "40 s, under the 60 s needed"}}))
    assert nonsense(root, "") == "data/evaluation/metrics.json: p.bias_radps is not finite"
    out.write_text(json.dumps({"p": {"bias_radps": None, "reason": "40 s, under the 60 s needed"}}))
    assert nonsense(root, "") == ""


@pytest.mark.parametrize(("code", "err", "expected"), [
    (2, "auvid: config error: {config}: field 'sync.rate_hz': must be > 0", "refused"),
    (2, "auvid: usage error: nothing to process", "unnamed"),
    (1, "  quarantined trial01.mcap: damaged", "quarantine"),
    (3, "auvid: run failed: no segment", "stage-failed"),
    (1, "Traceback (most recent call last):\n  ...\nTypeError: x", "traceback"),
    (-11, "", "traceback"),
    (-24, "", "hang"),
    (3, "numpy.core._exceptions._ArrayMemoryError: Unable to allocate 445. GiB", "memory"),
])
def test_an_exit_is_classified_as_the_readme_defines_it(tmp_path: Path, code: int, err: str, expected: str) -> None:
    config = tmp_path / "params.yaml"
    assert classify(code, "", err.format(config=config), _root(tmp_path), config)[0] == expected


@pytest.mark.parametrize(("stream", "key", "value", "named"), [
    ("depth", "topic", "/pressure/dpth", "streams.depth.topic"),
    ("dvl", "signals", {"dvl_x_mps": {"field": "velocity.xx"}}, "streams.dvl.signals.dvl_x_mps.field"),
])
def test_a_source_every_log_lacks_is_refused_naming_the_vehicle_file_and_key(
        raw: list[Path], tmp_path: Path, stream: str, key: str, value: Any, named: str) -> None:
    """Found by the run campaign: the refusal named the topic and the stream in its text, not the vehicle file and
    the key (as every other config refusal does)."""
    doc = copy.deepcopy(VEHICLE)
    if key == "signals":
        doc["streams"][stream]["signals"] = {**doc["streams"][stream]["signals"], **value}
    else:
        doc["streams"][stream][key] = value
    mcap = [p for p in raw if p.is_file()]  # the CSV trial reads its own files (trials.trial02 overrides them)
    result, detail, _ = run_config("vehicle", doc, [f"streams.{stream}.{key} = x"], mcap, tmp_path / "w", to="ingest")
    assert result == "refused" and f"field '{named}'" in detail and "every log (2)" in detail, detail
