"""Known answers for the coefficient intervals of Gertler-Hagen and McFarland-Whitcomb (``fit_intervals``, the block
bootstrap of pipeline.models.bootstrap with a refit per replicate): plants inside each family
(tests/models/test_explicit_eiv.py) whose accelerations carry AR(1) errors of known correlation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from pipeline.models.explicit import GertlerHagen, McFarlandWhitcomb
from tests.models.test_explicit_eiv import MAIN, dataset, true_theta


def _fit(cls, seed: int, rho: float = 0.9):
    _, _, _, X, y = dataset(cls, seed, n=2000)
    sd = 0.3 * y.std(axis=0)
    e = lfilter([np.sqrt(1 - rho**2)], [1.0, -rho], np.random.default_rng(1000 + seed).normal(size=y.shape), axis=0)
    yn = y + e * sd
    return cls(noise_std=(0, 0, 0, 0, 0, 0, *sd)).fit(X, yn), X, yn


@pytest.mark.parametrize("cls", [GertlerHagen, McFarlandWhitcomb])
def test_90_percent_intervals_cover_the_true_coefficients_under_correlated_errors(cls) -> None:
    """Test seeds 100-107 (validation 6-17: GH 0.889, MW 0.819 at rho 0.9; MW 0.903 with white errors)."""
    inside = []
    for seed in range(100, 108):
        model, X, y = _fit(cls, seed)
        ci = model.fit_intervals(X, y).coefficient_intervals_
        assert ci["replicates"] == 50 and ci["failed_replicates"] == 0 and ci["block_rows"] > 40
        truth = dict(zip(model.param_names, true_theta(model), strict=True))
        inside += [ci["intervals"][k][0] <= truth[k] <= ci["intervals"][k][1] for k in MAIN[cls]]
    assert 0.7 <= np.mean(inside) <= 0.99, np.mean(inside)


def test_every_parameter_has_a_centred_interval_and_the_refit_leaves_the_model_as_it_was() -> None:
    model, X, y = _fit(McFarlandWhitcomb, 3)
    coef = model.coef_.copy()
    ci = model.fit_intervals(X, y).coefficient_intervals_
    np.testing.assert_array_equal(model.coef_, coef)  # the replicates are fitted on a clone
    assert list(ci["intervals"]) == list(model.param_names) and "normal" in ci["method"]
    for k, (lo, hi) in ci["intervals"].items():
        assert lo < hi and (lo + hi) / 2 == pytest.approx(model.coefficients()[k], abs=1e-9 * max(1.0, abs(hi)))
    assert model.fit_intervals(X, y).coefficient_intervals_ == ci  # seeded


@pytest.mark.parametrize("chunks", [1, 3, 50])
def test_intervals_in_tasks_are_the_intervals_of_one_call(chunks):
    # The train stage runs the bootstrap's replicates as tasks (its span was one 2.6-s task); whatever the number of
    # chunks, joined in order they give the same record, to the bit, as one fit_intervals call.
    whole, X, y = _fit(McFarlandWhitcomb, 3)
    whole.fit_intervals(X, y, n_boot=12)
    split, _, _ = _fit(McFarlandWhitcomb, 3)
    plan, tasks = split.interval_tasks(X, y, n_boot=12, chunks=chunks)
    assert len(tasks) == min(chunks, 12)
    assert split.join_intervals(plan, [fn(*args) for fn, args in tasks]).coefficient_intervals_ \
        == whole.coefficient_intervals_
