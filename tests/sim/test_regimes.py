"""The "family" preset (issue 33 item 1): each trial's regime drawn from its seed, as stated, and the old presets
unchanged."""

from __future__ import annotations

import collections

import numpy as np
import pytest

from pipeline import physics
from pipeline.config.vehicle import Vehicle
from pipeline.sim import (
    PRESET_SEED_OFFSET,
    PRESETS,
    Controls,
    SensorOptions,
    SimTrial,
    generate_trial,
    load_example_vehicle,
    load_truth,
)
from pipeline.sim.disturbance import Disturbance
from pipeline.sim.regime import (
    AMPLITUDES_RPM,
    REDRAW_STEP,
    Regime,
    distinct_regime,
    draw_regime,
    family_trials,
)
from pipeline.sim.vehicle import Commander, Dynamics
from pipeline.vocabulary import force_columns
from tests.sim.test_presets import trial_digest

FAMILY = PRESET_SEED_OFFSET["family"]

#: sha256 of every truth column and every stream of a 10-s trial (2-s warm-up) of each old preset, taken before
#: the family preset was added: adding it must not move a byte of them.
BEFORE_FAMILY = {
    ("gentle", 3): "873e64ca942cb4d1531d651465871d21001c2b714cb7ab4677e4f0135624e5fc",
    ("hard", PRESET_SEED_OFFSET["hard"] + 5): "2fed98ddd972dbdf9f97dcaf6a082c85b3f407c7c50a6eb49a25461d4fc5914b",
}


def full_digest(trial: SimTrial) -> str:
    return trial_digest(trial, list(trial.truth.columns))


@pytest.fixture(scope="module")
def vehicle() -> Vehicle:
    return load_example_vehicle()


def horizontal(vehicle: Vehicle) -> np.ndarray:
    return np.flatnonzero(np.abs(physics.allocation_matrix(vehicle)[2]) < 0.9)


def first_seed(**want) -> int:
    """The first family seed whose regime has the given fields."""
    return next(s for s in range(FAMILY, FAMILY + 1000) if all(getattr(draw_regime(s), k) == v
                                                                for k, v in want.items()))


@pytest.mark.parametrize(("preset", "seed"), sorted(BEFORE_FAMILY))
def test_old_presets_are_byte_identical_to_before_the_family(vehicle: Vehicle, preset: str, seed: int) -> None:
    trial = generate_trial(vehicle, 10.0, seed=seed, warmup_s=2.0, preset=preset)
    assert full_digest(trial) == BEFORE_FAMILY[(preset, seed)]
    assert trial.regime is None


def test_family_has_its_own_seeds() -> None:
    assert "family" in PRESETS
    offsets = sorted(PRESET_SEED_OFFSET.values())
    assert len(offsets) == len(PRESETS) and all(b - a >= 3200 for a, b in zip(offsets, offsets[1:], strict=False))


def test_the_regime_is_a_pure_function_of_the_seed(vehicle: Vehicle) -> None:
    assert [draw_regime(s) for s in range(FAMILY, FAMILY + 50)] == [draw_regime(s) for s in range(FAMILY, FAMILY + 50)]
    assert len({draw_regime(s) for s in range(FAMILY, FAMILY + 50)}) > 10  # not one regime for every seed
    a = generate_trial(vehicle, 5.0, seed=FAMILY + 7, preset="family")
    b = generate_trial(vehicle, 5.0, seed=FAMILY + 7, preset="family")
    assert a.regime == b.regime == draw_regime(FAMILY + 7)
    assert full_digest(a) == full_digest(b)


def test_over_200_seeds_every_option_occurs_and_nothing_else() -> None:
    regimes = [draw_regime(s) for s in range(FAMILY, FAMILY + 200)]
    assert {r.n_sines for r in regimes} == {1, 2, 3}
    assert {r.amplitude_rpm for r in regimes} == {1300.0, 2600.0}
    assert {r.disturbance for r in regimes} == {True, False}
    assert {r.hall for r in regimes} == {True, False}
    assert {r.period_range_s for r in regimes} == {(5.0, 45.0)}
    counts = collections.Counter(r.kind() for r in regimes)
    assert len(counts) == 24 and min(counts.values()) >= 2  # every combination, none starved
    assert AMPLITUDES_RPM == (0.5 * Controls().amplitude_rpm, Controls().amplitude_rpm)  # the gentle preset's


def test_describe_says_what_was_drawn() -> None:
    assert Regime(2, 1300.0, True, False).describe() == (
        "2 sines/thruster, periods 5-45 s, 1300 rpm (half), tether on, Hall speeds off")
    assert Regime(1, 2600.0, False, True).describe() == (
        "1 sine/thruster, periods 5-45 s, 2600 rpm (full), tether off, Hall speeds on")


@pytest.mark.parametrize("n_sines", [1, 2, 3])
def test_commands_are_the_drawn_sines(vehicle: Vehicle, n_sines: int) -> None:
    """The trial's horizontal commands are exactly amplitude x the weighted sum of the drawn sines, periods in
    5-45 s; and their spectrum peaks at the drawn periods and nowhere else (one peak per sine)."""
    dyn, duration_s = Dynamics(vehicle, load_truth()), 1200.0

    def commander(seed: int) -> Commander:  # the trial's own, from its command child of the seed
        return Commander(dyn, draw_regime(seed).controls(),
                         np.random.default_rng(np.random.SeedSequence(seed).spawn(2)[0]))

    def resolved(seed: int) -> list[int]:  # horizontal thrusters whose sines are 8 bins apart or more
        return [k for k in horizontal(vehicle) if np.all(np.diff(np.sort(1 / commander(seed).periods[k])) >= 8 /
                                                         duration_s)]

    seed = next(s for s in range(FAMILY, FAMILY + 200)
                if draw_regime(s).n_sines == n_sines and len(resolved(s)) >= 2)
    regime, drawn = draw_regime(seed), commander(seed)
    trial = generate_trial(vehicle, duration_s, seed=seed, preset="family", rate_hz=20.0,
                           sensors=SensorOptions(noise=False))
    assert drawn.periods.shape == (len(vehicle.thrusters), n_sines)
    assert 5.0 <= drawn.periods.min() and drawn.periods.max() <= 45.0
    t_s = (trial.truth["t_ns"].to_numpy() - trial.truth["t_ns"].iloc[0]) / 1e9
    for k in horizontal(vehicle):
        cmd = trial.truth[f"n{k + 1}_cmd_rpm"].to_numpy()
        expected = regime.amplitude_rpm * (drawn.weights[k] * np.sin(
            2 * np.pi * t_s[:, None] / drawn.periods[k] + drawn.phases[k])).sum(axis=1)
        np.testing.assert_allclose(cmd, expected, atol=1e-9)
        assert np.abs(cmd).max() <= regime.amplitude_rpm
    for k in resolved(seed):
        cmd = trial.truth[f"n{k + 1}_cmd_rpm"].to_numpy()
        freqs, df = np.sort(1.0 / drawn.periods[k]), 1.0 / duration_s
        spectrum = np.abs(np.fft.rfft(cmd * np.hanning(cmd.size)))
        f_axis = np.fft.rfftfreq(cmd.size, d=t_s[1] - t_s[0])
        peaks = [i for i in range(1, spectrum.size - 1) if spectrum[i] >= spectrum[i - 1]
                 and spectrum[i] > spectrum[i + 1] and spectrum[i] > 0.2 * spectrum.max()]
        assert len(peaks) == n_sines
        np.testing.assert_allclose(f_axis[peaks], freqs, atol=1.5 * df)


def test_switches_make_the_trial(vehicle: Vehicle) -> None:
    on = generate_trial(vehicle, 20.0, seed=first_seed(disturbance=True, hall=True), preset="family")
    off = generate_trial(vehicle, 20.0, seed=first_seed(disturbance=False, hall=False), preset="family")
    # the tether: a force in surge and sway (its size: the next test), or none
    assert on.truth[force_columns("dist")].to_numpy()[:, [0, 1]].std(axis=0).min() > 0.1
    assert (off.truth[force_columns("dist")].to_numpy() == 0.0).all() and off.disturbance is None
    # Hall-counter speeds: 10-Hz windows in counts of 60 / (7 x 0.1) rpm; else the default 20-Hz sampled speeds
    assert on.sensors.thruster_counter_ppr == 7 and off.sensors.thruster_counter_ppr is None
    counts = on.streams["thrusters"].fields["velocity"] * 60.0 / (2 * np.pi) / (60.0 / 0.7)
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    assert len(on.streams["thrusters"]) == pytest.approx(200, abs=2)
    assert len(off.streams["thrusters"]) == pytest.approx(400, abs=4)
    # the hard preset's rate biases in every regime
    for trial in (on, off):
        assert trial.sensors.fog_bias_radps == 2e-4 and trial.sensors.earth_rate_latitude_deg == 45.0
        assert trial.truth["fog_bias_r_radps"].abs().min() > 1e-4


def test_the_tether_scales_with_the_thrust(vehicle: Vehicle) -> None:
    """A tether's drag grows as the speed squared, which the thrust sets: at half the amplitude (a quarter of the
    thrust) the family's tether is a quarter of the hard preset's, at full amplitude the hard preset's own."""
    hard = np.array(Disturbance.hard().sd)
    for amplitude, scale in ((2600.0, 1.0), (1300.0, 0.25)):
        trial = generate_trial(vehicle, 600.0, seed=first_seed(disturbance=True, amplitude_rpm=amplitude),
                               preset="family", rate_hz=10.0, warmup_s=1.0)
        np.testing.assert_allclose(trial.disturbance.sd, scale * hard, rtol=1e-12)
        force = trial.truth[force_columns("dist")].to_numpy()
        # an OU force of 30 s over 600 s: its sample SD within ~35 % of the stationary one
        np.testing.assert_allclose(force[:, [0, 1, 5]].std(axis=0), scale * hard[[0, 1, 5]], rtol=0.4)


def test_a_test_regime_differs_from_the_training_ones() -> None:
    # a seed's own regime when it differs
    seed = FAMILY + 3
    other = next(r for s in range(FAMILY, FAMILY + 100) if (r := draw_regime(s)).kind() != draw_regime(seed).kind())
    assert distinct_regime(seed, [other]) == (seed, draw_regime(seed))
    # else the first redraw seed + k * REDRAW_STEP whose regime differs from all the training ones
    taken = [draw_regime(seed), draw_regime(seed + REDRAW_STEP)]
    new_seed, regime = distinct_regime(seed, taken)
    k = (new_seed - seed) // REDRAW_STEP
    assert k >= 2 and new_seed == seed + k * REDRAW_STEP and regime == draw_regime(new_seed)
    assert regime.kind() not in {r.kind() for r in taken}
    assert all(draw_regime(seed + j * REDRAW_STEP).kind() in {r.kind() for r in taken} for j in range(k))
    # no way out: every kind taken
    every = [Regime(n, a, d, h) for n in (1, 2, 3) for a in AMPLITUDES_RPM for d in (0, 1) for h in (0, 1)]
    with pytest.raises(ValueError, match="no regime outside"):
        distinct_regime(seed, every, max_redraws=5)


def test_the_benchmarks_test_trial_never_repeats_a_training_regime() -> None:
    redrawn = 0
    for bench_seed in range(200):
        first = FAMILY + 100 * bench_seed + 1
        (s1, r1), (s2, r2), (s3, r3) = family_trials(first)
        assert (s1, s2) == (first, first + 1) and (r1, r2) == (draw_regime(s1), draw_regime(s2))
        assert r3 == draw_regime(s3) and r3.kind() not in {r1.kind(), r2.kind()}
        redrawn += s3 != first + 2
    assert 5 < redrawn < 60  # the rule was exercised (about 2 in 24 draws collide), and not for every seed
