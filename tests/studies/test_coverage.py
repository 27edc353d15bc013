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
from pipeline.studies.coverage import MAX_STRETCHES, excitation, input_coverage, stretches, study_coverage

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


# Two sinusoidal trials with the coupled models' default inputs, 10 Hz, periods incommensurate so that the training
# fills its box: the test trial is the training's generator again (other phases) except that sway thrust T_th2_N
# runs at twice the training amplitude in its second half.
INPUTS = ["u_mps", "v_mps", "r_radps", "T_th1_N", "T_th2_N", "T_th3_N"]
PERIODS_S = [13.77, 9.13, 7.31, 11.37, 6.07, 17.93]  # not multiples of the step: the training fills its range
DT_S = 0.1


def _sines(duration_s: float, phase: float, t0_ns: int, gain: np.ndarray | None = None) -> pd.DataFrame:
    t = np.arange(round(duration_s / DT_S)) * DT_S
    frame = pd.DataFrame({c: np.sin(2 * np.pi * t / p + phase * (k + 1)) for k, (c, p) in
                          enumerate(zip(INPUTS, PERIODS_S, strict=True))})
    if gain is not None:
        frame["T_th2_N"] *= gain
    return frame.assign(t_ns=t0_ns + np.round(t * 1e9).astype(np.int64))


def test_sway_thrust_twice_the_training_range_on_a_known_share_is_named_with_its_samples() -> None:
    """Known answer: 2·sin leaves [-1, 1] where |sin| > 1/2, 2/3 of the time, so 1/3 of a trial doubled on its second
    half; every extrapolated sample lies in that half; the largest excess is 2 - 1 = 1 = sqrt(2) SDs of a unit sine.
    Tolerance 0.005 on the share: each of the ~200 crossings of the bound can miscount one sample of 6000 and the
    miscounts' signs vary, so the error is a few samples (measured: under one sample); 0.005 is 30 samples."""
    train = _sines(1200.0, 0.0, 0).assign(trial="train")
    gain = np.where(np.arange(6000) >= 3000, 2.0, 1.0)
    test = _sines(600.0, 1.0, 10**12, gain).assign(trial="test")
    doc = study_coverage(train, test, {"wdse_svr": INPUTS})
    assert doc["flagged"] == {"test": ["T_th2_N"]}
    res = doc["groups"][0]["trials"]["test"]
    assert res["extrapolated_inputs"] == ["T_th2_N"] and res["outside"]
    by = {d["input"]: d for d in res["inputs"]}
    assert by["T_th2_N"]["share_outside_range"] == pytest.approx(1 / 3, abs=0.005)
    assert by["T_th2_N"]["max_excess_sd"] == pytest.approx(np.sqrt(2), rel=0.01)
    for c in INPUTS[:4] + INPUTS[5:]:  # other phases of the same sines: a few samples 1e-6 SD past a sampled peak
        assert by[c]["share_outside_range"] < 0.002 and by[c]["max_excess_sd"] < 1e-5 and not by[c]["extrapolated"]
    # which predictions: every flagged sample in the doubled half (from 300 s), about the input's share
    assert res["extrapolated_share"] == pytest.approx(1 / 3, abs=0.02)
    assert res["stretches"] and all(r["start_s"] >= 300.0 for r in res["stretches"])
    assert res["stretches_total"] >= 2 * 300 / PERIODS_S[4] - 2  # two excursions per period of 2·sin
    said = report_coverage.which("test", res)
    assert said.startswith("The predictions on 33") and f"in {res['stretches_total']} stretches" in said
    (advice,) = report_coverage.advice("test", res)
    assert advice.startswith("T_th2_N: 33") and "drives T_th2_N to" in advice
    # the same trial without the doubling is inside: nothing flagged, no extrapolated predictions
    inside = study_coverage(train, _sines(600.0, 1.0, 10**12).assign(trial="test"), {"wdse_svr": INPUTS})
    assert inside["flagged"] == {}
    entry = inside["groups"][0]["trials"]["test"]
    assert entry["extrapolated_share"] == 0.0 and entry["stretches"] == []
    assert report_coverage.which("test", entry) == ""


def test_extrapolated_samples_are_exactly_those_outside_with_their_times(train: pd.DataFrame) -> None:
    """Samples 100..199 of 500 (10 Hz) 3 SD out, one more at 450 that is 0.05 SD out on another input (not named,
    so not an extrapolation): one stretch 10.0-19.9 s; unsorted rows are put in time order first."""
    test = _uniform(np.random.default_rng(9), 500, 0.5).assign(t_ns=7 * 10**11 + np.arange(500) * 10**8)
    test.loc[100:199, "x2_N"] = train["x2_N"].max() + 3.0 * train["x2_N"].std(ddof=0)
    test.loc[450, "x1_N"] = train["x1_N"].max() + 0.05 * train["x1_N"].std(ddof=0)
    res = input_coverage(train, test.iloc[::-1], COLS)
    assert res["extrapolated_share"] == 0.2 and res["stretches_total"] == 1
    assert res["stretches"] == [{"start_s": 10.0, "end_s": 19.9, "samples": 100}]
    assert report_coverage.which("s", res) == "The predictions on 20 % of s's samples are extrapolations in 1 " \
                                              "stretch: 10–19.9 s."


def test_only_the_longest_stretches_are_listed_in_time_order() -> None:
    flagged = np.zeros(200, dtype=bool)
    runs = [(k * 15, k * 15 + 1 + k % 4) for k in range(12)]  # 12 runs of 1-4 samples
    for a, b in runs:
        flagged[a:b] = True
    listed, total = stretches(flagged, np.arange(200) * 10**9)
    assert total == 12 and len(listed) == MAX_STRETCHES
    assert [r["start_s"] for r in listed] == sorted(r["start_s"] for r in listed)
    dropped = {float(a) for a, _ in runs} - {r["start_s"] for r in listed}
    assert dropped == {60.0, 120.0}  # three runs of 1 sample (at 0, 60, 120 s): the earliest kept
