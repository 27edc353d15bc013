"""The report warns where a model's unseen trial parts from its cross-validation by more than the folds' spread."""

from __future__ import annotations

import re

from pipeline.report.studies import cv_against_unseen, label


def _entry(mean: float, sd: float, unseen: float) -> dict:
    return {"cv": {"udot_mps2": {"test_r2": {"mean": mean, "sd": sd}}}, "final": {"udot_mps2": {"r2": unseen}}}


def test_only_the_pairs_outside_the_fold_spread_are_named_with_the_gap_and_the_search_score() -> None:
    doc = {"wdse_svr": _entry(0.990, 0.001, 0.960),      # 0.030 below, 6 x the floor of 0.005: optimistic
           "rbf_svr": _entry(0.950, 0.020, 0.940),       # inside its spread
           "two_weights_svr": _entry(0.970, 0.0, 0.973),  # 0.003 above: inside the 0.005 floor
           "graybox": _entry(0.900, 0.010, 0.930),       # 0.030 above: the unseen trial does better
           "gertler_hagen": {"failed": {"reason": "x"}}}
    trace = {"wdse_svr": {"udot_mps2": {"best_score": 0.9951}}}
    html = cv_against_unseen(doc, ["udot_mps2"], trace)
    rows = re.findall(r"<tr>(.*?)</tr>", html, flags=re.S)[1:]
    cells = [re.findall(r"<td[^>]*>(.*?)</td>", r, flags=re.S) for r in rows]
    assert [c[0] for c in cells] == [label("wdse_svr"), label("graybox")]
    assert "0.9951" in cells[0][2] and "-0.030 (6.0 × the spread)" in cells[0][5] and "optimistic" in cells[0][6]
    assert "+0.030 (3.0 × the spread)" in cells[1][5] and "better" in cells[1][6]
    assert "1 of 2 model–output pair(s)" in html


def test_nothing_is_said_when_every_unseen_score_lies_within_its_folds() -> None:
    assert cv_against_unseen({"rbf_svr": _entry(0.95, 0.02, 0.94)}, ["udot_mps2"], None) == ""


def test_the_protocol_line_says_how_the_searches_folds_cut_the_rows():
    from pipeline.report.studies import protocol_line

    doc = {"tuning": "nested", "tuned_on": "train_test", "n_tuning_rows": 9000, "max_samples": 600,
           "fold_evals": 8, "tuning_cv": "auto"}
    assert "hold out whole training trials" in protocol_line({**doc, "search_folds": ["trials"]})
    blocked = protocol_line({**doc, "search_folds": ["blocked"], "tuning_cv": "blocked"})
    assert "blocked folds" in blocked and "(coupled.tuning_cv: blocked)" in blocked
    assert "tuning_cv" not in protocol_line(doc)  # a file from before the key: nothing said
