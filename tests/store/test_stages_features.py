"""End to end over the simulator: accelerations and damping targets against its truth; the four stage shells."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pytest

from pipeline import physics, store
from pipeline.config import Params, Vehicle, load_params
from pipeline.config.params import SyncParams
from pipeline.derive import derive
from pipeline.estimation.differentiate import kinematics
from pipeline.estimation.gaussian import gaussian_filters, gaussian_truncate
from pipeline.sim import SensorOptions, StreamSpec, example_vehicle_path, generate_trial, load_example_vehicle
from pipeline.sync import resample, synchronize
from pipeline.tableio import read_meta, write_parquet
from pipeline.units import conversion
from pipeline.vocabulary import ACCELERATION, DOFS, SMOOTH, force_columns
from stages import derive as derive_stage
from stages import differentiate as differentiate_stage
from stages import features as features_stage
from stages import sync as sync_stage

DURATION_S = 30.0
TRUTH_DT_S = 0.005  # the simulator's 200 Hz


def signal_tables(trial, vehicle: Vehicle) -> dict[str, pd.DataFrame]:
    """What ingest makes of the simulated streams (signals contract), for the fields the DAGON config uses."""
    by_topic = {s.topic: s for s in trial.streams.values()}
    out = {}
    for name, src in vehicle.streams.items():
        s = by_topic[src.topic]
        cols = {"t_ns": ((s.header_ns if src.clock == "header" else s.log_ns)
                         + int(round(src.offset_s * 1e9))).astype(np.int64)}
        for sig, field in src.signals.items():
            if sig.endswith("_quat"):
                cols.update({f"{sig}_{p}": s.fields[f"{field.field}.{p}"].astype(float) for p in "wxyz"})
                continue
            if "[name=" in field.field:
                base, joint = field.field[:-1].split("[name=")
                raw = s.fields[base][:, s.joint_names.index(joint)]
            else:
                raw = s.fields[field.field]
            unit = conversion(sig, field.unit)
            cols[sig] = raw.astype(float) * unit.factor + unit.offset
        out[name] = pd.DataFrame(cols)
    return out


@pytest.fixture(scope="module")
def vehicle() -> Vehicle:
    return load_example_vehicle()


#: These tests check the Gaussian method's arithmetic (kernel, edges, noise gain) against the truth, so they pin it
#: and a DVL of regular 4 Hz pings with plain white noise (the kalman method's tests are
#: tests/estimation/test_estimation.py).
GAUSSIAN = Params.model_validate({"differentiate": {"method": "gaussian", "sigma_s": 0.25}})
PLAIN_DVL = dict(dvl=StreamSpec(4.0, 0.020, -0.05, 0.005), dvl_ping_interval_s=None, dvl_outlier_rate=0.0,
                 dvl_scale_error=0.0, dvl_misalignment_rpy_deg=(0.0, 0.0, 0.0), dvl_averaging_s=0.0,
                 dvl_lock_loss_fraction=0.0)


@pytest.fixture(scope="module")
def clean(vehicle: Vehicle):
    return generate_trial(vehicle, DURATION_S, seed=1, sensors=SensorOptions(noise=False, dropouts=False))


@pytest.fixture(scope="module")
def noisy(vehicle: Vehicle):
    # DAGON's sensors (noise, rates, stamps) with more frequent DVL dropouts, so that 30 s have some
    return generate_trial(vehicle, DURATION_S, seed=2, sensors=SensorOptions(dropout_bursts_per_min=4.0,
                                                                             dropout_duration_s=(1.0, 3.0),
                                                                             **PLAIN_DVL))


def _pipeline(trial, vehicle: Vehicle) -> pd.DataFrame:
    params = GAUSSIAN
    synced = synchronize(signal_tables(trial, vehicle), vehicle, params.sync)
    return derive(kinematics(synced, vehicle, params.differentiate), vehicle)


def _truth_at(trial, t_ns: np.ndarray, cols: list[str], smooth: bool) -> np.ndarray:
    truth = trial.truth
    rows = np.searchsorted(truth["t_ns"].to_numpy(), t_ns)
    assert np.array_equal(truth["t_ns"].to_numpy()[rows], t_ns)
    values = truth[cols].to_numpy()
    if smooth:  # the same kernel the pipeline applies, on the 200 Hz truth (whole trial: no edge effects inside)
        d = GAUSSIAN.differentiate
        values, _ = gaussian_filters(values, TRUTH_DT_S, d.sigma_s, d.gaussian_degree, 6.0)
    return values[rows]


def _rms(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(np.square(x), axis=0))


def test_noise_free_accelerations_and_damping_match_truth(clean, vehicle: Vehicle) -> None:
    out = _pipeline(clean, vehicle)
    t = out["t_ns"].to_numpy()
    # the derivative of the smoothed velocity is the smoothed acceleration: compare with the smoothed truth.
    # What remains is the 4 Hz DVL's linear interpolation (and 20 Hz zero-order hold of the speeds): < 1 %.
    ref = _truth_at(clean, t, ACCELERATION, smooth=True)
    got = out[ACCELERATION].to_numpy()
    for j in (0, 1, 5):  # u, v, r: the excited DOFs
        assert _rms(got[:, j] - ref[:, j]) < 0.01 * _rms(ref[:, j]), ACCELERATION[j]
    # tau is exact (same thrust curve, speeds sampled on the grid)
    tau_true = _truth_at(clean, t, force_columns("tau"), smooth=False)
    assert out[force_columns("tau")].to_numpy() == pytest.approx(tau_true, abs=1e-9)
    # d differs from the true damping by M times the smoothing bias of nu_dot (what a Gaussian of sigma
    # removes from the true acceleration), plus the interpolation error above: allow 1.2x that, + 2 % of d.
    M = physics.mass_matrix(vehicle)
    bias = (_truth_at(clean, t, ACCELERATION, smooth=False) - ref) @ M.T
    d_true = _truth_at(clean, t, force_columns("d"), smooth=False)
    err = out[force_columns("d")].to_numpy() - d_true
    for j in (0, 1, 5):
        assert _rms(err[:, j]) < 1.2 * _rms(bias[:, j]) + 0.02 * _rms(d_true[:, j]), DOFS[j]


def _dvl_derivative_noise_gain(vehicle: Vehicle, dvl_hz: float) -> float:
    """Std of the Gaussian derivative of unit white noise sampled at the DVL rate and linearly interpolated to
    the grid: the pipeline is linear in the noise, so this is the norm of its impulse response (phase-averaged)."""
    params = GAUSSIAN
    grid_dt_ns = int(1e9 / params.sync.rate_hz)
    n_dvl = 80
    t_dvl = np.arange(n_dvl, dtype=np.int64) * int(1e9 / dvl_hz)
    grid = np.arange(0, t_dvl[-1] + 1, grid_dt_ns, dtype=np.int64)
    interp, _ = resample(t_dvl, np.eye(n_dvl), np.ones(n_dvl, bool), grid, "linear", 10**9)
    d = params.differentiate
    _, resp = gaussian_filters(interp, grid_dt_ns / 1e9, d.sigma_s, d.gaussian_degree, gaussian_truncate(d.edge_sigmas))
    mid = slice(len(grid) // 2 - 10, len(grid) // 2 + 10)
    return float(np.sqrt(np.mean(np.sum(resp[mid] ** 2, axis=1))))


def test_noisy_accelerations_and_damping_within_noise(noisy, vehicle: Vehicle) -> None:
    out = _pipeline(noisy, vehicle)
    opts = noisy.sensors
    t = out["t_ns"].to_numpy()
    dvl = noisy.streams["dvl"]
    lost = dvl.header_ns[~dvl.fields["bottom_lock"].astype(bool)] + int(round(vehicle.streams["dvl"].offset_s * 1e9))
    assert lost.size > 0  # this seed has dropouts: no kept sample lies within a DVL period of a lost-lock sample
    assert np.abs(t[:, None] - lost[None, :]).min() >= int(1e9 / opts.dvl.rate_hz)
    ref = _truth_at(noisy, t, ACCELERATION, smooth=True)
    err = out[ACCELERATION].to_numpy() - ref
    # DVL noise (isotropic, so the 45 deg mount rotation keeps it per axis) through interpolation + derivative
    sigma_lin = opts.dvl.noise * _dvl_derivative_noise_gain(vehicle, opts.dvl.rate_hz)
    # an rms over ~350 samples correlated over the ~1.5 s kernel (~12 independent windows) estimates sigma_lin
    # within ~20 % (1/sqrt(2*12)): allow 1.5x (2.5 of those), plus the noise-free interpolation error (< 1 %)
    for j in (0, 1, 2):
        assert _rms(err[:, j]) < 1.5 * sigma_lin + 0.01 * _rms(ref[:, j]), ACCELERATION[j]
    assert _rms(err[:, j]) > 0.5 * sigma_lin  # the prediction is not vacuous
    # damping target: its noise is M times the acceleration noise (tau is noise-free up to rpm noise)
    M = physics.mass_matrix(vehicle)
    d_true = _truth_at(noisy, t, force_columns("d"), smooth=False)
    bias = (_truth_at(noisy, t, ACCELERATION, smooth=False) - ref) @ M.T
    d_err = out[force_columns("d")].to_numpy() - d_true
    for j in (0, 1):
        sigma_d = sigma_lin * np.linalg.norm(M[j, :3])
        assert _rms(d_err[:, j]) < 1.5 * sigma_d + 1.2 * _rms(bias[:, j]) + 0.02 * _rms(d_true[:, j])


# ---- the stage shells -------------------------------------------------------------------------------------


def _write_signals(root: Path, trial_name: str, tables: dict[str, pd.DataFrame]) -> None:
    for stream, frame in tables.items():
        write_parquet(pa.Table.from_pandas(frame, preserve_index=False),
                      root / "data/signals" / trial_name / f"{stream}.parquet", {"trial": trial_name, "stream": stream})


def _run_all(root: Path, vehicle: Vehicle, params: Params) -> dict[str, object]:
    return {name: module.run(root, vehicle, params) for name, module in
            (("sync", sync_stage), ("differentiate", differentiate_stage), ("derive", derive_stage),
             ("features", features_stage))}


def test_stages_end_to_end_quarantine_and_byte_identical_rerun(tmp_path: Path, noisy, vehicle: Vehicle) -> None:
    tables = signal_tables(noisy, vehicle)
    _write_signals(tmp_path, "01", tables)
    bad = dict(tables)
    bad["fog"] = bad["fog"].assign(t_ns=bad["fog"]["t_ns"] + 10**12)  # no overlap with the rest
    _write_signals(tmp_path, "bad", bad)
    params = Params(features={"tuning_fraction": 0.25})
    results = _run_all(tmp_path, vehicle, params)
    sync = results["sync"]
    assert [e["trial"] for e in sync.quarantined] == ["bad"]
    assert "overlap" in sync.quarantined[0]["reason"] and sync.quarantined[0]["error"] == "SyncError"
    for name in ("differentiate", "derive", "features"):  # differentiate: + its estimation report
        assert results[name].quarantined == [] and len(results[name].outputs) == 1 + (name == "differentiate"), name
    frame = store.load(tmp_path)
    assert set(frame["trial"]) == {"01"} and set(frame["vehicle"]) == {"dagon"}
    assert set(frame["split"]) == {"tuning", "train_test"}
    assert {*SMOOTH, "d_u_N", "T_th1_N", "n5_rpm", "segment", "udot_std_mps2", "u_smooth_std_mps", "u_meas_mps",
            "d_std_u_N"} <= set(frame.columns)
    files = sorted((tmp_path / "data").rglob("*.parquet")) + sorted((tmp_path / "data").rglob("*.json"))
    before = {p: p.read_bytes() for p in files}
    _run_all(tmp_path, vehicle, params)
    assert {p: p.read_bytes() for p in files} == before
    meta = read_meta(store.partition_dir(tmp_path, "dagon", "01") / store.PART_FILE)
    assert meta["inputs"][0]["file"] == "data/derived/01.parquet" and len(meta["inputs"][0]["sha256"]) == 64
    assert meta["params"] == {"tuning_fraction": 0.25, "test_trials": []}
    assert len(meta["config_hash"]) == 64 and len(meta["params_hash"]) == 64


@pytest.mark.parametrize("method", ["kalman", "gaussian", "savgol"])
def test_the_store_holds_exactly_the_columns_known_before_any_stage(tmp_path: Path, clean, vehicle: Vehicle,
                                                                     method: str) -> None:
    """``auvid run`` refuses ``coupled.inputs`` naming a column the store will not have before its first stage, from
    :func:`store.store_columns` (the vehicle config and the method, no data): it must name what the stages write."""
    _write_signals(tmp_path, "01", signal_tables(clean, vehicle))  # no drop-outs: segments long enough for any method
    results = _run_all(tmp_path, vehicle, Params(differentiate={"method": method}))
    assert not results["features"].quarantined and results["features"].outputs
    written = set(store.dataset(tmp_path).schema.names) - {"vehicle", "trial"}
    assert written == set(store.store_columns(vehicle, method))
    for params in (Params(), load_params(Path(__file__).resolve().parents[2] / "params.yaml")):  # the defaults pass
        assert {*params.coupled.inputs, *params.coupled.outputs} <= written


def test_stage_main_with_trial_and_exit_codes(tmp_path: Path, noisy, vehicle: Vehicle) -> None:
    tables = signal_tables(noisy, vehicle)
    _write_signals(tmp_path, "01", tables)
    common = ["--root", str(tmp_path), "--vehicle", str(example_vehicle_path())]
    assert sync_stage.main([*common, "--trial", "01"]) == 0
    assert (tmp_path / "data/synced/01.parquet").exists()
    # a params file demanding longer segments than the trial has: quarantined, exit code 1, stale output gone
    (tmp_path / "params.yaml").write_text("sync:\n  min_segment_s: 1000\n")
    assert sync_stage.main(common) == 1
    assert not (tmp_path / "data/synced/01.parquet").exists()
    assert SyncParams(min_segment_s=1000).min_segment_s == 1000


def test_reads_what_the_real_ingest_writes(tmp_path: Path, noisy, vehicle: Vehicle) -> None:
    """Contract check with the ingest stage: a simulated MCAP log through ingest, then the four stages."""
    from pipeline.sim import write_trial
    from stages import ingest as ingest_stage

    (tmp_path / "data/raw").mkdir(parents=True)
    write_trial(noisy, "mcap", tmp_path / "data/raw/trial7.mcap")
    params = GAUSSIAN
    assert ingest_stage.run(tmp_path, vehicle, params).quarantined == []
    results = _run_all(tmp_path, vehicle, params)
    assert all(not r.quarantined for r in results.values())
    assert {name: len(r.outputs) for name, r in results.items()} == {
        name: 2 if name == "differentiate" else 1 for name in results}  # + the estimation report
    frame = store.load(tmp_path, trials="trial7")
    direct = _pipeline(noisy, vehicle)  # the same signals, assembled in this test
    assert frame["t_ns"].tolist() == direct["t_ns"].tolist()
    assert frame["udot_mps2"].to_numpy() == pytest.approx(direct["udot_mps2"].to_numpy(), abs=1e-12)
