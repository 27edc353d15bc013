"""A family of excitation regimes (issue 33, item 1): each trial of the ``"family"`` preset draws its own.

A real campaign's trials differ in more than their noise: the pilot runs one, two or three summed sines per
thruster, at half or full thrust, with or without a tether pulling, with the thruster speeds from the ESC or
counted off a Hall sensor. :func:`draw_regime` draws one such regime as a pure function of the simulator seed
(its own child of the seed, so the commands, sensor noise and disturbance draws are those of any other preset):

- ``n_sines``: 1, 2 or 3 summed sines per horizontal thruster, each period drawn uniformly in
  :data:`PERIOD_RANGE_S` (5-45 s) by the commander, as in every preset;
- ``amplitude_rpm``: half or full of the gentle preset's 2600 rpm (:data:`AMPLITUDES_RPM`);
- ``disturbance``: the hard preset's tether-like force (:meth:`Disturbance.hard`) scaled to the regime's thrust,
  × (amplitude / 2600 rpm)² (a tether's drag grows as the speed squared, which the thrust sets), or none;
- ``hall``: Hall-counter thruster speeds (:meth:`SensorOptions.hard`) or the default sampled ones;
- always the hard preset's rate-sensor biases (gyros, FOG, the Earth's rate).

:func:`distinct_regime` is the benchmark's rule for a test trial: redraw (seed + k * :data:`REDRAW_STEP`, k = 1,
2, ...) until its regime's :meth:`Regime.kind` is none of the training trials'; :func:`family_trials` gives the
seeds and regimes of a benchmark's training and test trials by that rule.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from pipeline.sim.disturbance import Disturbance
from pipeline.sim.sensors import SensorOptions
from pipeline.sim.vehicle import Controls

PERIOD_RANGE_S = (5.0, 45.0)
#: Half and full of the gentle preset's thruster amplitude (``Controls().amplitude_rpm``, 2600 of 3500 rpm).
AMPLITUDES_RPM = (1300.0, 2600.0)
N_SINES = (1, 2, 3)
#: A redraw's seed step: far above every preset's seed range (offsets 0, 3200, 6400; 100 per benchmark seed).
REDRAW_STEP = 100_000
#: Child of ``SeedSequence(seed)`` the regime is drawn from (0: commands, 1: sensors, 2: disturbance).
REGIME_CHILD = 3


@dataclass(frozen=True)
class Regime:
    """One trial's excitation regime: what :func:`draw_regime` drew and what it makes of the trial."""

    n_sines: int
    amplitude_rpm: float
    disturbance: bool
    hall: bool
    period_range_s: tuple[float, float] = PERIOD_RANGE_S

    def kind(self) -> tuple[int, float, bool, bool]:
        """What two regimes must differ in to count as different: sines, thrust level and the two switches."""
        return (self.n_sines, self.amplitude_rpm, self.disturbance, self.hall)

    def describe(self) -> str:
        """One line, e.g. ``2 sines/thruster, periods 5-45 s, 1300 rpm (half), tether on, Hall speeds off``."""
        level = "full" if self.amplitude_rpm == max(AMPLITUDES_RPM) else "half"
        lo, hi = self.period_range_s
        return (f"{self.n_sines} sine{'s' if self.n_sines > 1 else ''}/thruster, periods {lo:g}-{hi:g} s, "
                f"{self.amplitude_rpm:.0f} rpm ({level}), tether {'on' if self.disturbance else 'off'}, "
                f"Hall speeds {'on' if self.hall else 'off'}")

    def controls(self) -> Controls:
        return Controls(amplitude_rpm=self.amplitude_rpm, period_range_s=self.period_range_s, n_sines=self.n_sines)

    def sensors(self) -> SensorOptions:
        """The hard preset's sensors (rate biases, Hall counter); without ``hall`` the default thruster stream."""
        hard = SensorOptions.hard()
        if self.hall:
            return hard
        default = SensorOptions()
        return dataclasses.replace(hard, thruster_counter_ppr=default.thruster_counter_ppr,
                                   thrusters=default.thrusters)

    def disturbance_model(self) -> Disturbance | None:
        """The tether at this regime's thrust: the hard preset's SDs × (amplitude / full amplitude)²; or none."""
        if not self.disturbance:
            return None
        hard = Disturbance.hard()
        scale = (self.amplitude_rpm / max(AMPLITUDES_RPM)) ** 2
        return Disturbance(sd=tuple(scale * sd for sd in hard.sd), time_constant_s=hard.time_constant_s)


def draw_regime(seed: int) -> Regime:
    """The regime of simulator seed ``seed``: a pure function of it, each option equally likely."""
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(REGIME_CHILD + 1)[REGIME_CHILD])
    n_sines = int(rng.choice(N_SINES))
    amplitude = float(rng.choice(AMPLITUDES_RPM))
    disturbance, hall = (bool(b) for b in rng.integers(0, 2, size=2))
    return Regime(n_sines, amplitude, disturbance, hall)


def distinct_regime(seed: int, training: Iterable[Regime], max_redraws: int = 100) -> tuple[int, Regime]:
    """(seed, regime) for a test trial: ``seed``'s own regime unless its :meth:`Regime.kind` is a training trial's,
    else the first of ``seed + k * REDRAW_STEP`` (k = 1, 2, ...) whose is none of theirs."""
    taken = {r.kind() for r in training}
    for k in range(max_redraws + 1):
        candidate = seed + k * REDRAW_STEP
        regime = draw_regime(candidate)
        if regime.kind() not in taken:
            return candidate, regime
    raise ValueError(f"no regime outside the training trials' {sorted(taken)} in {max_redraws} redraws of {seed}")


def family_trials(first_seed: int, n_train: int = 2) -> list[tuple[int, Regime]]:
    """(simulator seed, regime) of ``n_train`` training trials (seeds ``first_seed``, ``first_seed + 1``, ...) and
    one test trial after them whose regime differs from every training trial's (:func:`distinct_regime`)."""
    train = [(first_seed + k, draw_regime(first_seed + k)) for k in range(n_train)]
    return [*train, distinct_regime(first_seed + n_train, [r for _, r in train])]
