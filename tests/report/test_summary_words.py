"""The one-line verdict's word for the best coupled model's R² on the unseen trial: a weak or negative "best" is
flagged where it is shown (issue 34, item 5)."""

from __future__ import annotations

import pytest

from pipeline.report.studies import Part
from pipeline.report.summary import verdict_lines


@pytest.mark.parametrize("r2,word", [(0.95, "(good)"), (0.49, "(weak)"), (0.1, "(poor)"),
                                     (-0.04, "(worse than the mean there: no model to trust on this output)")])
def test_the_best_models_score_gets_a_word_and_a_negative_one_a_flag(r2: float, word: str) -> None:
    coupled = Part(outputs=["udot_mps2"], headline=[{"output": "u̇ [m/s²]", "best model": "Gertler–Hagen",
                                                     "R² on the unseen trial": r2}])
    [line] = verdict_lines(coupled, Part(), Part(), None)
    assert line == f"u̇ [m/s²]: Gertler–Hagen is best, R² {r2:.3g} on the unseen trial {word}"
