"""The tune stage's extrapolation diagnostics and the report's section, on a simulated store whose test trial is
pushed outside the training on one input: the stage writes coverage.json before any search, and the report names
the trial, the input and the excitation that would fix it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline import layout, store
from pipeline.config import Params
from stages import report as report_stage
from stages import tune as tune_stage
from tests.studies.helpers import coupled_store

# s3, the test trial, is s1 again (the same seed, 1000 s later) and every row is training (tuning_fraction 0): each
# of its samples is a training sample, until one input is pushed out. (A test trial of its own seed, 13, leaves the
# 40-s training on sway thrust by 3.6 SDs on 16 % of its samples: genuinely outside, no known answer.)
TRIALS = {"s1": 11, "s2": 12, "s3": 11}
PUSHED = "T_th2_N"


def _push(root: Path, vehicle: str, trial: str, column: str, share: float, sd_beyond: float) -> tuple[float, float]:
    """Set ``column`` of the first ``share`` of ``trial``'s rows to the training maximum + ``sd_beyond`` training SDs;
    returns (training max, training SD)."""
    train = store.load(root, split="train_test", columns=[column])[column].to_numpy()
    hi, sd = float(train.max()), float(train.std())
    path = store.partition_dir(root, vehicle, trial) / store.PART_FILE
    table = pq.read_table(path)
    frame = table.to_pandas()
    n = round(share * len(frame))
    frame.loc[: n - 1, column] = hi + sd_beyond * sd
    pq.write_table(pa.Table.from_pandas(frame, schema=table.schema, preserve_index=False), path)
    return hi, sd


@pytest.fixture(scope="module")
def pushed_run(tmp_path_factory) -> tuple[Path, Params, object]:
    root = tmp_path_factory.mktemp("coverage")
    params = Params(features={"test_trials": ["s3"], "tuning_fraction": 0.0},
                    coupled={"folds": 3, "max_evals": 4, "max_samples": 200})
    vehicle = coupled_store(root, TRIALS, 40.0, params)
    return root, params, vehicle


def test_tune_writes_the_coverage_before_the_search_and_the_report_names_the_input(pushed_run, monkeypatch
                                                                                   ) -> None:
    root, params, vehicle = pushed_run
    before = tune_stage._coverage(root, vehicle, params)
    assert before["flagged"] == {}, before["flagged"]  # a copy of a training trial is inside the training
    assert all(d["share_outside_range"] == 0 for g in before["groups"] for d in g["trials"]["s3"]["inputs"])
    _push(root, vehicle.name, "s3", PUSHED, 0.2, 3.0)
    searched = []
    monkeypatch.setattr(tune_stage, "tune_stage", lambda frame, *a, **k: searched.append(
        layout.coverage_path(root).exists()) or ({"hyperparameters": {}}, {}))
    result = tune_stage.run(root, vehicle, params)
    assert searched == [True]  # written before the search runs
    doc = json.loads(layout.coverage_path(root).read_text())
    assert layout.coverage_path(root) in result.outputs
    assert doc["training_trials"] == ["s1", "s2"] and doc["test_trials"] == ["s3"]
    assert doc["flagged"] == {"s3": [PUSHED]}
    (svr,) = [g for g in doc["groups"] if "wdse_svr" in g["models"]]
    assert PUSHED in svr["inputs"] and set(svr["models"]) == {"rbf_svr", "two_weights_svr", "wdse_svr"}
    for group in doc["groups"]:  # the explicit models take tau, not the thrusters': untouched, inside
        assert group["trials"]["s3"]["outside"] == (PUSHED in group["inputs"]), group["models"]
    entry = svr["trials"]["s3"]
    assert entry["extrapolated_inputs"] == [PUSHED]
    (pushed,) = [d for d in entry["inputs"] if d["input"] == PUSHED]
    assert pushed["share_outside_range"] == pytest.approx(0.2, abs=1 / entry["rows"])
    assert pushed["max_excess_sd"] == pytest.approx(3.0, rel=1e-9)
    assert svr["excitation"]["inputs"][PUSHED]["ratio"] < 1.0
    # which predictions: the pushed first 20 % (one stretch from the trial's first sample), and the few of the
    # training's own tail beyond the hull (s3 is s1: its ~0.5 % beyond the training's 99.5 % quantile)
    assert 0.2 - 1 / entry["rows"] <= entry["extrapolated_share"] <= 0.21
    first = entry["stretches"][0]
    assert first["start_s"] == 0.0 and first["samples"] >= round(0.2 * entry["rows"]) - 1
    report_stage.run(root, vehicle, params)
    text = (root / "reports/report.html").read_text()
    section = text.split('<section id="extrapolation">', 1)[1].split("</section>", 1)[0]
    assert f"the predictions on s3 ({PUSHED}) are extrapolations" in section
    assert f"add a training trial that drives {PUSHED} to" in section
    assert "of s3&#x27;s samples are extrapolations in 1 stretch" in section  # ' escaped
    assert "Extrapolation:</b> the predictions on s3" in text.split('<section id="summary">', 1)[1].split(
        "</section>", 1)[0]
    assert np.isfinite(pushed["train_max"])
