"""How good are the differentiate stage's targets on a realistic trial, and how fast is the smoother?

Quality (issue 12's acceptance, issue 32's presets): per preset and seed, a 480-s DAGON trial from the project's
simulator, through the real ingest -> sync -> differentiate (-> derive, for d) stages with default params. Two
presets (``pipeline.sim.trial``): ``gentle``, the simulator's default (three summed sines per thruster, periods
6-45 s, 2600 rpm, realistic sensors: 3.6 Hz DVL, 0.02 m/s noise, outliers, 20 % lost lock in bursts, scale error,
misalignment), and ``hard`` (one sinusoid per thruster, periods 5-18 s, 1800 rpm, a tether-like disturbance force,
Hall-counter thruster speeds, gyro/FOG biases with the Earth's rate). ``--seeds K`` are indices: the gentle
trial of index K is simulator seed K, the hard one seed 3200 + K (``pipeline.sim.PRESET_SEED_OFFSET``).

Scores, over the grid samples differentiate returns (the usable ones): ``usable``, the usable fraction of the grid;
``R2_*dot``, R² of the estimated u̇ v̇ ṙ against the simulator's true accelerations; ``cover_*``, the fraction of
samples whose true value lies within the estimate's 2-sigma band, for ν (u v r), ν̇ (u̇ v̇ ṙ) and the damping
target d (``d_*`` against ``d_std_*`` from ``pipeline.derive.derive``, truth: ``d_true_*``, the true damping less
the disturbance, which is what d equals with exact ν, ν̇ and τ); ``hf_*dot``, the share of the true acceleration's
power above 0.2 Hz (the band a 3.6 Hz DVL with 2 cm/s noise resolves little of): the periodogram of the true
acceleration over the whole trial at the simulator's rate, mean removed, power at f > 0.2 Hz over all power at
f > 0. Per preset and method: the mean over seeds and the worst seed (lowest value; for ``hf_*``, highest).

Speed: the smoother on a one-hour trial (the same simulator, 3600 s), timed as the differentiate stage's work
(``pipeline.estimation.differentiate.differentiate``) against reading that trial's Parquet inputs in the same run
(ratio), wall and CPU time.

    python bench/estimation.py                         # both presets, 5 seeds x 480 s, then the one-hour timing
    python bench/estimation.py --preset hard --seeds 0 1 --methods kalman --skip-speed
    python bench/estimation.py --seeds 0 1 --methods kalman gaussian --skip-speed
    python bench/estimation.py --methods kalman kalman-kinematic --skip-speed   # with and without the model
    python bench/estimation.py --methods kalman --accelerometer --skip-speed   # + IMU accelerometers

``--accelerometer``: the trial's AHRS accelerometers (the simulator's: 0.02 m/s^2 white noise, a constant bias per
axis) configured in a copy of the example vehicle (``sensors.accelerometer``), scored as ``kalman+imu`` beside the
methods without them, on the same trial.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.config import Params  # noqa: E402
from pipeline.sim import PRESET_SEED_OFFSET, PRESETS, generate_trial, load_example_vehicle, write_trial  # noqa: E402
from pipeline.vocabulary import accel_std_column, force_column, std_column  # noqa: E402

DOFS = (("u", "mps"), ("v", "mps"), ("r", "radps"))
DVL_BAND_HZ = 0.2  # above this, a 3.6 Hz DVL with 2 cm/s noise resolves little of the acceleration
KEYS = ["usable", "R2_udot", "R2_vdot", "R2_rdot", "cover_u", "cover_v", "cover_r", "cover_udot", "cover_vdot",
        "cover_rdot", "cover_d_u", "cover_d_v", "cover_d_r", "hf_udot", "hf_vdot", "hf_rdot"]


def high_frequency_share(x: np.ndarray, rate_hz: float, above_hz: float = DVL_BAND_HZ) -> float:
    """Share of the power of ``x`` (mean removed) at frequencies above ``above_hz``, from its periodogram."""
    power = np.abs(np.fft.rfft(x - x.mean())) ** 2
    freq = np.fft.rfftfreq(x.size, 1.0 / rate_hz)
    total = power[freq > 0].sum()
    return float(power[freq > above_hz].sum() / total) if total > 0 else 0.0


def vehicle_with_accelerometer():
    """The example vehicle with its AHRS's accelerometers configured (the simulator's IMU position)."""
    import yaml

    from pipeline.config.vehicle import Vehicle
    from pipeline.sim import SensorOptions, example_vehicle_path

    raw = yaml.safe_load(example_vehicle_path().read_text())
    raw["streams"]["ahrs"]["signals"].update(
        {f"a{a}_imu_mps2": {"field": f"linear_acceleration.{a}", "unit": "m/s^2"} for a in "xyz"})
    raw["sensors"]["accelerometer"] = {"signals": [f"a{a}_imu_mps2" for a in "xyz"],
                                       "position_m": list(SensorOptions().imu_position_m)}
    return Vehicle.model_validate(raw)


def prepare(root: Path, seed: int, duration_s: float, params: Params, vehicle=None, preset: str = "gentle"):
    """Simulate (``seed`` is the simulator's), write MCAP, ingest and sync one trial; returns (vehicle, trial)."""
    from stages import ingest, sync

    vehicle = vehicle if vehicle is not None else load_example_vehicle()
    trial = generate_trial(vehicle, duration_s, seed=seed, warmup_s=20.0, preset=preset)
    (root / "data/raw").mkdir(parents=True, exist_ok=True)
    write_trial(trial, "mcap", root / "data/raw/trial.mcap")
    for stage in (ingest, sync):
        result = stage.run(root, vehicle, params)
        if result.quarantined:
            raise SystemExit(f"{stage.NAME}: {result.quarantined}")
    return vehicle, trial


def score(root: Path, vehicle, trial, params: Params) -> dict[str, float]:
    from pipeline import layout
    from pipeline.derive import derive
    from pipeline.estimation.differentiate import differentiate
    from pipeline.tableio import read_parquet

    synced = read_parquet(layout.synced_path(root, "trial"))[0].to_pandas()
    streams = {f.stem: read_parquet(f)[0] for f in sorted(layout.signals_dir(root, "trial").glob("*.parquet"))}
    kin, report = differentiate(synced, vehicle, params.differentiate, streams)
    truth = trial.truth.set_index("t_ns")
    rows = truth.loc[kin["t_ns"].to_numpy()]
    derived = derive(kin, vehicle) if std_column("u") in kin.columns else None
    rate_hz = 1e9 / float(np.median(np.diff(trial.truth["t_ns"].to_numpy())))
    out = {"usable": report["usable_fraction"]}
    for dof, unit in DOFS:
        acc, vel = f"{dof}dot_{unit}2", f"{dof}_{unit}"
        a_true = rows[acc].to_numpy()
        err = kin[acc].to_numpy() - a_true
        out[f"R2_{dof}dot"] = 1.0 - np.mean(err**2) / np.var(a_true)
        out[f"hf_{dof}dot"] = high_frequency_share(trial.truth[acc].to_numpy(), rate_hz)
        if std_column(dof) in kin.columns:
            ev = np.abs(kin[vel].to_numpy() - rows[vel].to_numpy())
            out[f"cover_{dof}"] = float(np.mean(ev <= 2 * kin[std_column(dof)].to_numpy()))
            out[f"cover_{dof}dot"] = float(np.mean(np.abs(err) <= 2 * kin[accel_std_column(dof)].to_numpy()))
        if derived is not None and force_column(dof, "d_std") in derived.columns:
            ed = np.abs(derived[force_column(dof, "d")].to_numpy() - rows[force_column(dof, "d_true")].to_numpy())
            out[f"cover_d_{dof}"] = float(np.mean(ed <= 2 * derived[force_column(dof, "d_std")].to_numpy()))
    return out


def quality(presets: list[str], seeds: list[int], methods: list[str], duration_s: float,
            accelerometer: bool = False) -> None:
    rows = []
    imu = vehicle_with_accelerometer() if accelerometer else None
    for preset in presets:
        for index in seeds:
            seed = PRESET_SEED_OFFSET[preset] + index
            with tempfile.TemporaryDirectory() as tmp:
                root = Path(tmp)
                params = Params()
                _, trial = prepare(root, seed, duration_s, params, imu, preset)
                vehicle = load_example_vehicle()
                for method in methods:
                    # "kalman-kinematic": the kalman method without the vehicle's model (model_passes 0)
                    how = ({"method": "kalman", "model_passes": 0} if method == "kalman-kinematic"
                           else {"method": method})
                    p = Params.model_validate({"differentiate": how})
                    rows.append((preset, method, seed, score(root, vehicle, trial, p)))
                if imu is not None:
                    rows.append((preset, "kalman+imu", seed, score(root, imu, trial, Params())))
    if imu is not None:
        methods = [*methods, "kalman+imu"]
    print(f"\n{duration_s:.0f}-s trials, each preset's sensors, default params per method")
    print("| preset | method | seed | " + " | ".join(KEYS) + " |")
    print("| --- | --- | ---: | " + " | ".join("---:" for _ in KEYS) + " |")
    cell = lambda res, k: f"{res[k]:.3f}" if k in res else "n/a"  # noqa: E731
    for preset, method, seed, res in rows:
        print(f"| {preset} | {method} | {seed} | " + " | ".join(cell(res, k) for k in KEYS) + " |")
    for preset in presets:
        for method in methods:
            sel = [r for p, m, _, r in rows if p == preset and m == method]
            mean = {k: np.mean([r[k] for r in sel]) for k in KEYS if k in sel[0]}
            worst = {k: (np.max if k.startswith("hf_") else np.min)([r[k] for r in sel]) for k in KEYS if k in sel[0]}
            print(f"| {preset} | {method} | mean | " + " | ".join(cell(mean, k) for k in KEYS) + " |")
            print(f"| {preset} | {method} | worst | " + " | ".join(cell(worst, k) for k in KEYS) + " |")


def speed(duration_s: float, repeat: int) -> None:
    import resource

    from pipeline import layout
    from pipeline.estimation.differentiate import differentiate
    from pipeline.tableio import read_parquet

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        params = Params()
        vehicle, _ = prepare(root, 0, duration_s, params)
        files = [layout.synced_path(root, "trial"),
                 *sorted(layout.signals_dir(root, "trial").glob("*.parquet"))]
        read_t, smooth_t, smooth_cpu = [], [], []
        for _ in range(repeat):
            t0 = time.perf_counter()
            synced = read_parquet(files[0])[0].to_pandas()
            streams = {f.stem: read_parquet(f)[0] for f in files[1:]}
            read_t.append(time.perf_counter() - t0)
            c0 = resource.getrusage(resource.RUSAGE_SELF)
            t0 = time.perf_counter()
            kin, _ = differentiate(synced, vehicle, params.differentiate, streams)
            smooth_t.append(time.perf_counter() - t0)
            c1 = resource.getrusage(resource.RUSAGE_SELF)
            smooth_cpu.append(c1.ru_utime + c1.ru_stime - c0.ru_utime - c0.ru_stime)
        print(f"\nsmoothing a {duration_s:.0f}-s trial ({len(synced)} grid samples, "
              f"{sum(len(s) for s in streams.values())} native samples), median of {repeat}")
        print("| what | wall s | CPU s | ratio to reading the inputs |")
        print("| --- | ---: | ---: | ---: |")
        r, s = float(np.median(read_t)), float(np.median(smooth_t))
        print(f"| read the Parquet inputs | {r:.3f} | | 1.0 |")
        print(f"| differentiate (kalman, ML process noise, variances) | {s:.3f} | {np.median(smooth_cpu):.3f} | "
              f"{s / r:.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", nargs="+", choices=PRESETS, default=["gentle", "hard"],
                    help="simulator presets to score (default gentle and hard; 'family': a regime per trial); "
                         "quality only, the timing uses gentle")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4],
                    help="seed indices: gentle K is simulator seed K, hard K is seed 3200 + K, family K 6400 + K")
    ap.add_argument("--duration", type=float, default=480.0)
    ap.add_argument("--methods", nargs="+", default=["kalman", "gaussian"])
    ap.add_argument("--speed-duration", type=float, default=3600.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--accelerometer", action="store_true", help="also the kalman method with the IMU's "
                    "accelerometers configured (kalman+imu)")
    ap.add_argument("--skip-quality", action="store_true")
    args = ap.parse_args()
    if not args.skip_quality:
        quality(args.preset, args.seeds, args.methods, args.duration, args.accelerometer)
    if not args.skip_speed:
        speed(args.speed_duration, args.repeat)


if __name__ == "__main__":
    main()
