"""Extrapolation and excitation diagnostics (issue 33, item 5) on frames whose answer is built in: a test trial with
one input 3 training SDs beyond the range on 20 % of its samples, one inside, one whose inputs are each inside their
range but combined as the training never did, and a training that barely excited one input."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from pipeline.errors import ModelError
from pipeline.report import coverage as report_coverage
from pipeline.studies.coverage import excitation, input_coverage, study_coverage

COLS = ["x1_N", "x2_N", "x3_mps"]


def _uniform(rng: np.random.Generator, n: int, half: float, cols=COLS) -> pd.DataFrame:
    return pd.DataFrame({c: rng.uniform(-half, half, n) for c in cols})


@pytest.fixture
def train() -> pd.DataFrame:
    return _uniform(np.random.default_rng(0), 4000, 1.0)


def test_one_input_3_sd_beyond_on_20_percent_is_named_with_the_shares_as_built(train: pd.DataFrame) -> None:
    test = _uniform(np.random.default_rng(1), 500, 0.5)
    hi, sd = train["x2_N"].max(), train["x2_N"].std(ddof=0)
    test.loc[:99, "x2_N"] = hi + np.linspace(2.5, 3.0, 100) * sd  # 100 of 500 samples, 2.5 to 3 SD beyond
    res = input_coverage(train, test, COLS)
    assert res["extrapolated_inputs"] == ["x2_N"] and res["outside"]
    by = {d["input"]: d for d in res["inputs"]}
    assert by["x2_N"]["share_outside_range"] == 0.2 and by["x2_N"]["share_outside_quantiles"] == 0.2
    assert by["x2_N"]["max_excess_sd"] == pytest.approx(3.0, rel=1e-12)
    assert by["x2_N"]["max_excess"] == pytest.approx(3.0 * sd, rel=1e-12)
    for other in ("x1_N", "x3_mps"):
        assert by[other]["share_outside_range"] == 0.0 and by[other]["max_excess_sd"] == 0.0
        assert not by[other]["extrapolated"]
    # inside samples (|x| <= 0.5 of a unit cube) are well inside the hull: exactly the 20 % are beyond it
    assert res["hull"]["share_beyond"] == 0.2 and res["hull"]["outside"] and res["hull"]["drivers"] == ["x2_N"]


def test_a_test_trial_inside_the_training_is_not_flagged(train: pd.DataFrame) -> None:
    res = input_coverage(train, _uniform(np.random.default_rng(2), 500, 0.9), COLS)
    assert not res["outside"] and res["extrapolated_inputs"] == []
    assert all(d["share_outside_range"] == 0.0 for d in res["inputs"])
    assert res["hull"]["share_beyond"] <= 0.05 and res["hull"]["drivers"] == []


def test_a_sliver_just_past_the_edge_and_a_single_spike_are_not_named(train: pd.DataFrame) -> None:
    """5 % of the samples 0.05 SD past the maximum: outside the range, but not by enough to name; one sample of 400
    3 SD out: far, but too few to be a regime the models are asked about."""
    test = _uniform(np.random.default_rng(3), 400, 0.5)
    test.loc[:19, "x1_N"] = train["x1_N"].max() + 0.05 * train["x1_N"].std(ddof=0)
    test.loc[20, "x2_N"] = train["x2_N"].max() + 3.0 * train["x2_N"].std(ddof=0)  # one spike: 0.25 %
    res = input_coverage(train, test, COLS)
    assert res["inputs"][0]["share_outside_range"] == 0.05 and res["inputs"][1]["share_outside_range"] == 0.0025
    assert res["inputs"][1]["max_excess_sd"] == pytest.approx(3.0) and res["extrapolated_inputs"] == []


def test_inputs_each_inside_but_combined_as_never_trained_are_flagged_by_the_hull() -> None:
    rng = np.random.default_rng(4)
    n = 4000
    x1 = rng.uniform(-1, 1, n)
    train = pd.DataFrame({"x1_N": x1, "x2_N": x1 + rng.normal(0, 0.05, n), "x3_mps": rng.uniform(-1, 1, n)})
    t1 = rng.uniform(-0.7, 0.7, 500)
    test = pd.DataFrame({"x1_N": t1, "x2_N": -t1, "x3_mps": rng.uniform(-0.7, 0.7, 500)})
    res = input_coverage(train, test, COLS)
    assert res["extrapolated_inputs"] == [] and all(d["share_outside_range"] == 0 for d in res["inputs"])
    assert res["hull"]["share_beyond"] > 0.8 and res["outside"]
    assert res["hull"]["drivers"] == ["x1_N", "x2_N"]
    (pair,) = res["hull"]["driver_correlations"]
    assert pair["inputs"] == ["x1_N", "x2_N"] and pair["train_r"] > 0.99 and pair["test_r"] == pytest.approx(-1)
    text = " ".join(report_coverage.advice("s3", res))
    assert "combine x1_N, x2_N" in text and "excites x1_N, x2_N together" in text


def test_hull_drivers_are_the_inputs_that_explain_most_of_the_excursion(train: pd.DataFrame) -> None:
    """x1 3 SD out on 20 % of the samples, x3 3 SD out on another 5 %: 25 % beyond the hull; without x3 20 % are
    still beyond (not a driver), without x1 only 5 % (the driver)."""
    test = _uniform(np.random.default_rng(8), 400, 0.5)
    for col, rows in (("x1_N", slice(0, 79)), ("x3_mps", slice(80, 99))):
        test.loc[rows, col] = train[col].max() + 3.0 * train[col].std(ddof=0)
    res = input_coverage(train, test, COLS)
    assert res["hull"]["share_beyond"] == 0.25 and res["hull"]["drivers"] == ["x1_N"]
    assert res["extrapolated_inputs"] == ["x1_N", "x3_mps"]


def test_the_least_excited_input_is_found() -> None:
    rng = np.random.default_rng(5)
    train = pd.DataFrame({"x1_N": rng.uniform(-1, 1, 3000), "x2_N": rng.uniform(-1, 1, 3000),
                          "x3_mps": rng.uniform(-0.2, 0.2, 3000)})
    res = excitation(train, _uniform(rng, 1000, 1.0), COLS)
    assert res["lowest"] == "x3_mps" and res["least_excited"] == ["x3_mps"]
    assert res["inputs"]["x3_mps"]["ratio"] == pytest.approx(0.2, abs=0.02)
    assert res["inputs"]["x1_N"]["ratio"] == pytest.approx(1.0, abs=0.05)
    assert excitation(train, train.iloc[:0], COLS)["lowest"] is None


def test_an_input_constant_in_training_that_moves_in_the_test_is_named() -> None:
    rng = np.random.default_rng(6)
    train = _uniform(rng, 1000, 1.0).assign(x3_mps=0.0)
    res = input_coverage(train, _uniform(rng, 200, 0.5), COLS)
    x3 = res["inputs"][2]
    assert x3["max_excess_sd"] is None and x3["extrapolated"] and res["extrapolated_inputs"] == ["x3_mps"]
    json.dumps(res, allow_nan=False)  # None, never NaN or inf, in the JSON


def test_missing_column_is_a_model_error_naming_it(train: pd.DataFrame) -> None:
    with pytest.raises(ModelError, match=r"test rows lack the input column\(s\) \['x3_mps'\]"):
        input_coverage(train, train.drop(columns="x3_mps"), COLS)


def test_study_document_groups_models_by_inputs_and_flags_the_trials(train: pd.DataFrame) -> None:
    rng = np.random.default_rng(7)
    inside, outside = _uniform(rng, 300, 0.5), _uniform(rng, 300, 0.5)
    outside.loc[:59, "x1_N"] = 1.5
    test = pd.concat([inside.assign(trial="in"), outside.assign(trial="out")], ignore_index=True)
    doc = study_coverage(train.assign(trial="s1"), test,
                         {"rbf_svr": COLS, "wdse_svr": COLS, "gertler_hagen": ["x1_N", "x2_N"]})
    assert [g["models"] for g in doc["groups"]] == [["rbf_svr", "wdse_svr"], ["gertler_hagen"]]
    assert doc["flagged"] == {"out": ["x1_N"]} and doc["test_trials"] == ["in", "out"]
    assert doc["training_trials"] == ["s1"] and doc["groups"][0]["trials"]["out"]["inputs"][0][
        "share_outside_range"] == 0.2
    again = study_coverage(train.assign(trial="s1"), test,
                           {"rbf_svr": COLS, "wdse_svr": COLS, "gertler_hagen": ["x1_N", "x2_N"]})
    assert json.dumps(doc, sort_keys=True) == json.dumps(again, sort_keys=True)
    advice = report_coverage.advice("out", doc["groups"][0]["trials"]["out"])
    assert len(advice) == 1 and advice[0].startswith("x1_N: 20 % of out's samples lie outside the training range")
    assert "add a training trial that drives x1_N to" in advice[0] and "1.5 N" in advice[0]
