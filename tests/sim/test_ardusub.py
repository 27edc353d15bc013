"""The simulated ArduSub depth-hold trial and its mavros logs (issue 34, item 3): a trial without attitude written
by the libraries' own writers, read back by rosbags, gives the simulator's servo outputs and rel_alt exactly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.sim.ardusub import HeaveTruth, heave_trial, thrust_N, thrust_table
from pipeline.sim.writers import write_trial


@pytest.fixture(scope="module")
def trial():
    return heave_trial(20.0, seed=3)


def test_truth_obeys_the_heave_equation_and_heaves_both_ways(trial) -> None:
    h, t = trial.heave, trial.truth
    m33 = h.mass_kg + h.added_mass_kg
    w = t["w_mps"].to_numpy()
    force = 2 * thrust_N(t["pwm_us"].to_numpy()) - h.net_buoyancy_N - h.z_w * w - h.z_ww * w * np.abs(w)
    np.testing.assert_allclose(t["wdot_mps2"], force / m33, atol=1e-12)
    dt = 1e-3
    np.testing.assert_allclose(np.gradient(t["depth_m"].to_numpy(), dt)[1:-1], w[1:-1], atol=1e-3)
    assert w.min() < -0.2 and w.max() > 0.2
    pwm, kgf = thrust_table()
    assert thrust_N(1500) == 0.0 and thrust_N(1900) == pytest.approx(5.0 * 9.80665) and kgf[pwm == 1100] == -4.0


@pytest.mark.parametrize("fmt", ["ros1", "ros2-sqlite3", "ros2-mcap"])
def test_a_trial_without_attitude_is_written_with_mavros_topics_and_types(trial, tmp_path: Path, fmt: str) -> None:
    from rosbags.highlevel import AnyReader

    path = write_trial(trial, fmt, tmp_path / ("hold.bag" if fmt == "ros1" else "hold"))
    with AnyReader([path]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types == {"/mavros/rc/out": "mavros_msgs/msg/RCOut",
                         "/mavros/global_position/rel_alt": "std_msgs/msg/Float64"}
        msgs: dict[str, list] = {}
        for conn, t_ns, raw in reader.messages():
            msgs.setdefault(conn.topic, []).append((t_ns, reader.deserialize(raw, conn.msgtype)))
    rc = np.array([list(m.channels) for _, m in msgs["/mavros/rc/out"]])
    alt = np.array([m.data for _, m in msgs["/mavros/global_position/rel_alt"]])
    log_ns = np.array([t for t, _ in msgs["/mavros/rc/out"]])
    np.testing.assert_array_equal(rc, trial.streams["rc"].fields["channels"])
    np.testing.assert_array_equal(log_ns, trial.streams["rc"].log_ns)
    np.testing.assert_array_equal(alt, trial.streams["rel_alt"].fields["data"])
    # rel_alt is up: minus the depth at its samples (3 mm of noise)
    depth = np.interp(trial.streams["rel_alt"].header_ns, trial.truth["t_ns"], trial.truth["depth_m"])
    assert np.std(alt + depth) == pytest.approx(0.003, rel=0.3)
    assert (rc[:, 4] == rc[:, 5]).all() and (rc[:, :4] == 1500).all() and rc[:, 4].std() > 30


def test_the_same_seed_gives_the_same_bytes(tmp_path: Path) -> None:
    a = write_trial(heave_trial(5.0, seed=1, heave=HeaveTruth(net_buoyancy_N=1.0)), "ros1", tmp_path / "a.bag")
    b = write_trial(heave_trial(5.0, seed=1, heave=HeaveTruth(net_buoyancy_N=1.0)), "ros1", tmp_path / "b.bag")
    assert a.read_bytes() == b.read_bytes()


def test_the_csv_layout_of_a_vehicle_without_attitude_ingests_to_the_same_signals(trial, tmp_path: Path) -> None:
    """csv_vehicle needed sensors.attitude; a level, heave-only vehicle's CSV variant now maps channels[4] to the
    column channels.4 and keeps rel_alt's sign."""
    import yaml

    from pipeline.config import Params, load_vehicle
    from pipeline.layout import stream_path
    from pipeline.sim.ardusub import thrust_table_csv
    from pipeline.sim.writers import csv_vehicle
    from pipeline.tableio import read_parquet
    from stages import ingest as ingest_stage

    table = {"table": "table.csv", "table_pwm_column": "PWM (µs)", "table_thrust_column": "Force (Kg f)",
             "table_thrust_unit": "kgf"}
    doc = {"name": "rov", "rigid_body": {"mass_kg": 11.5, "inertia_kgm2": np.diag([0.16] * 3).tolist()},
           "added_mass": np.diag([5.5, 12.7, 14.57, 0.12, 0.12, 0.12]).tolist(),
           "thrusters": [{"name": f"t{k}", "pwm_signal": f"pwm{k}_s", "position_m": [0.0, y, 0.0],
                          "direction": [0.0, 0.0, 1.0], "thrust": table} for k, y in ((5, 0.2), (6, -0.2))],
           "sensors": {"position": {"signals": ["depth_m"], "components": ["z"]}, "depth": "depth_m"},
           "streams": {"rel_alt": {"topic": "/mavros/global_position/rel_alt", "clock": "log",
                                   "signals": {"depth_m": {"field": "data", "unit": "m", "sign": -1}}},
                       "rc": {"topic": "/mavros/rc/out", "clock": "header",
                              "signals": {f"pwm{k}_s": {"field": f"channels[{k - 1}]", "unit": "us"}
                                          for k in (5, 6)}}}}
    (tmp_path / "rov.yaml").write_text(yaml.safe_dump(doc, allow_unicode=True))
    (tmp_path / "table.csv").write_text(thrust_table_csv(), encoding="utf-8")
    vehicle = csv_vehicle(load_vehicle(tmp_path / "rov.yaml"))
    assert vehicle.sensors.attitude is None and vehicle.streams["rc"].signals["pwm5_s"].field == "channels.4"
    write_trial(trial, "csv", tmp_path / "hold01")
    result = ingest_stage.run(tmp_path / "run", vehicle, Params(), logs=[tmp_path / "hold01"])
    assert not result.quarantined, result.quarantined
    rc = read_parquet(stream_path(tmp_path / "run", "hold01", "rc"))[0].to_pandas()
    np.testing.assert_allclose(rc["pwm5_s"], trial.streams["rc"].fields["channels"][:, 4] * 1e-6, rtol=1e-12)
    alt = read_parquet(stream_path(tmp_path / "run", "hold01", "rel_alt"))[0].to_pandas()
    np.testing.assert_allclose(alt["depth_m"], -trial.streams["rel_alt"].fields["data"], rtol=1e-12)
