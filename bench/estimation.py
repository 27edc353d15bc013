"""How good are the differentiate stage's targets on a realistic trial, and how fast is the smoother?

Quality (issue 12's acceptance): per seed, a 480-s DAGON trial from the project's simulator with its default,
realistic sensors (3.6 Hz DVL, 0.02 m/s noise, outliers, 20 % lost lock in bursts, scale error, misalignment;
sinusoidal thruster excitation), through the real ingest -> sync -> differentiate stages with default params;
the estimated accelerations are scored against the simulator's true accelerations at the same grid samples
(R² over the usable samples), the usable fraction of the grid, and the coverage of the true velocity by the
smoother's 2-sigma band.

Speed: the smoother on a one-hour trial (the same simulator, 3600 s), timed as the differentiate stage's work
(``pipeline.estimation.differentiate.differentiate``) against reading that trial's Parquet inputs in the same run
(ratio), wall and CPU time.

    python bench/estimation.py                         # 5 seeds x 480 s, then the one-hour timing
    python bench/estimation.py --seeds 0 1 --methods kalman gaussian --skip-speed
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
from pipeline.sim import generate_trial, load_example_vehicle, write_trial  # noqa: E402
from pipeline.vocabulary import accel_std_column, std_column  # noqa: E402

DOFS = (("u", "mps"), ("v", "mps"), ("r", "radps"))


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


def prepare(root: Path, seed: int, duration_s: float, params: Params, vehicle=None):
    """Simulate, write MCAP, ingest and sync one trial; returns (vehicle, trial)."""
    from stages import ingest, sync

    vehicle = vehicle if vehicle is not None else load_example_vehicle()
    trial = generate_trial(vehicle, duration_s, seed=seed, warmup_s=20.0)
    (root / "data/raw").mkdir(parents=True, exist_ok=True)
    write_trial(trial, "mcap", root / "data/raw/trial.mcap")
    for stage in (ingest, sync):
        result = stage.run(root, vehicle, params)
        if result.quarantined:
            raise SystemExit(f"{stage.NAME}: {result.quarantined}")
    return vehicle, trial


def score(root: Path, vehicle, trial, params: Params) -> dict[str, float]:
    from pipeline import layout
    from pipeline.estimation.differentiate import differentiate
    from pipeline.tableio import read_parquet

    synced = read_parquet(layout.synced_path(root, "trial"))[0].to_pandas()
    streams = {f.stem: read_parquet(f)[0] for f in sorted(layout.signals_dir(root, "trial").glob("*.parquet"))}
    kin, report = differentiate(synced, vehicle, params.differentiate, streams)
    truth = trial.truth.set_index("t_ns")
    rows = truth.loc[kin["t_ns"].to_numpy()]
    out = {"usable": report["usable_fraction"]}
    for dof, unit in DOFS:
        acc, vel = f"{dof}dot_{unit}2", f"{dof}_{unit}"
        a_true = rows[acc].to_numpy()
        err = kin[acc].to_numpy() - a_true
        out[f"R2_{dof}dot"] = 1.0 - np.mean(err**2) / np.var(a_true)
        if std_column(dof) in kin.columns:
            ev = np.abs(kin[vel].to_numpy() - rows[vel].to_numpy())
            out[f"cover_{dof}"] = float(np.mean(ev <= 2 * kin[std_column(dof)].to_numpy()))
            out[f"cover_{dof}dot"] = float(np.mean(np.abs(err) <= 2 * kin[accel_std_column(dof)].to_numpy()))
    return out


def quality(seeds: list[int], methods: list[str], duration_s: float, accelerometer: bool = False) -> None:
    rows = []
    imu = vehicle_with_accelerometer() if accelerometer else None
    for seed in seeds:
        with tempfile.TemporaryDirectory() as tmp:
            root = Path(tmp)
            params = Params()
            _, trial = prepare(root, seed, duration_s, params, imu)
            vehicle = load_example_vehicle()
            for method in methods:
                p = Params.model_validate({"differentiate": {"method": method}})
                rows.append((method, seed, score(root, vehicle, trial, p)))
            if imu is not None:
                rows.append(("kalman+imu", seed, score(root, imu, trial, Params())))
    if imu is not None:
        methods = [*methods, "kalman+imu"]
    keys = ["usable", "R2_udot", "R2_vdot", "R2_rdot", "cover_u", "cover_v", "cover_r", "cover_udot", "cover_vdot",
            "cover_rdot"]
    print(f"\n{duration_s:.0f}-s trials, default realistic sensors, default params per method")
    print("| method | seed | " + " | ".join(keys) + " |")
    print("| --- | ---: | " + " | ".join("---:" for _ in keys) + " |")
    for method, seed, res in rows:
        print(f"| {method} | {seed} | " + " | ".join(f"{res[k]:.3f}" if k in res else "n/a" for k in keys) + " |")
    for method in methods:
        sel = [r for m, _, r in rows if m == method]
        mean = {k: np.mean([r[k] for r in sel]) for k in keys if k in sel[0]}
        worst = {k: np.min([r[k] for r in sel]) for k in keys if k in sel[0]}
        print(f"| {method} | mean | " + " | ".join(f"{mean[k]:.3f}" if k in mean else "n/a" for k in keys) + " |")
        print(f"| {method} | worst | " + " | ".join(f"{worst[k]:.3f}" if k in worst else "n/a" for k in keys) + " |")


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
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
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
        quality(args.seeds, args.methods, args.duration, args.accelerometer)
    if not args.skip_speed:
        speed(args.speed_duration, args.repeat)


if __name__ == "__main__":
    main()
