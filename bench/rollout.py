"""Free runs of a 480-s trial: every coupled and decoupled model, wall and CPU time, and the ratio to one SVR
predict over the same rows (the rows a rollout evaluates: steps x 4 RK4 stages x batch members).

The models are fitted here on a synthetic plant with known damping (``pipeline.sim.synthetic.SyntheticPlant``, 20 Hz):
RBF-, 2-weights- and WDSE-SVR on ``[u v r n1 n2 n3]`` (libsvm through ``pipeline.models.svr``), the gray box
(McFarland-Whitcomb on ``[u v r tau_u tau_v tau_r]`` + a WDSE-SVR per output on its residual), the decoupled
LS, KRR, SVR and GP on each DOF's damping (GP with its 32-member posterior band). Each model's free run, horizon
errors (1, 5, 10 s) and, for the decoupled ones, DVL-outage bridging (10, 30, 60 s) are timed as the simulate
stage runs them.

The coupled models run as the simulate stage runs them: per model, its free runs over every segment and all
horizon windows in one batch (``run_model``); all decoupled models, the GP's band members included, in one
batch (``run_models``, one call per RK4 stage); bridging of all of them and all outage lengths in one batch.

Usage: nice python bench/rollout.py [trial_s=480] [train_s=300] [mode=stage]

``mode``: ``stage`` (as the simulate stage runs: one BLAS thread, every model through its fast predictor) or
``predict`` (as before issue 35: BLAS's default threads, the gray box through scikit-learn's ``predict``).

Results: docs/benchmarks.md, "Free-run rollouts" (figures of the re-layout's move: docs/benchmarks.md).
"""

from __future__ import annotations

import contextlib
import sys
import time

import numpy as np
from threadpoolctl import threadpool_limits

from pipeline.models.decoupled import make_estimator
from pipeline.models.explicit import McFarlandWhitcomb
from pipeline.models.graybox import GrayBox
from pipeline.models.svr import RBFSVR, WDSESVR, PerOutputRegressor, TwoWeightsSVR
from pipeline.physics import coriolis_force
from pipeline.rollout import (
    CoupledDynamics,
    DecoupledDynamics,
    band_tables,
    bridge_outages,
    damping_tables,
    run_model,
    run_models,
    table_range,
)
from pipeline.sim.synthetic import SyntheticPlant, synthetic_trial
from pipeline.vocabulary import TAU_COLUMNS, VELOCITY_COLUMNS

DOFS = ["u", "v", "r"]
RPM = ["n1_rpm", "n2_rpm", "n3_rpm"]


def clock() -> tuple[float, float]:
    return time.perf_counter(), time.process_time()


def main() -> None:
    trial_s = float(sys.argv[1]) if len(sys.argv) > 1 else 480.0
    train_s = float(sys.argv[2]) if len(sys.argv) > 2 else 300.0
    mode = sys.argv[3] if len(sys.argv) > 3 else "stage"
    if mode not in ("stage", "predict"):
        raise SystemExit(f"mode must be 'stage' or 'predict', got {mode!r}")
    plant = SyntheticPlant()
    train = synthetic_trial(plant, duration_s=train_s, seed=1)
    test = synthetic_trial(plant, duration_s=trial_s, seed=2, gap_s=(0.4 * trial_s, 0.4 * trial_s + 5.0))
    vel = [VELOCITY_COLUMNS[d] for d in DOFS]
    nu_tr, tau_tr = train[vel].to_numpy(), train[[TAU_COLUMNS[d] for d in DOFS]].to_numpy()
    acc = plant.dynamics(nu_tr, tau_tr)
    acc += 0.02 * acc.std(axis=0) * np.random.default_rng(0).standard_normal(acc.shape)
    X = np.hstack([nu_tr, train[RPM].to_numpy()])
    eps = [0.05 * float(a.std()) for a in acc.T]
    coupled = {
        "rbf_svr": PerOutputRegressor([RBFSVR(gamma=0.2, C=1.0, epsilon=e) for e in eps]),
        "two_weights_svr": PerOutputRegressor([TwoWeightsSVR(gamma_velocity=0.3, gamma_actuator=0.1, C=1.0,
                                                             epsilon=e) for e in eps]),
        "wdse_svr": PerOutputRegressor([WDSESVR(gammas=[0.3, 0.2, 0.3, 0.1, 0.1, 0.1], C=1.0, epsilon=e)
                                        for e in eps]),
    }
    for est in coupled.values():
        est.fit(X, acc)
    # the gray box on the study's columns [u v r tau_u tau_v tau_r n1 n2 n3]: base on the first six, residual on
    # the velocities and the thruster speeds
    X_gb = np.hstack([nu_tr, tau_tr, train[RPM].to_numpy()])
    graybox = GrayBox(base=McFarlandWhitcomb(solver="ols"),
                      residual=PerOutputRegressor([WDSESVR(gammas=[0.3, 0.2, 0.3, 0.1, 0.1, 0.1], C=1.0, epsilon=e)
                                                   for e in eps]),
                      residual_columns=(0, 1, 2, 6, 7, 8)).fit(X_gb, acc)
    n_sv = {m: [e.n_support_ for e in est.estimators_] for m, est in coupled.items()}
    n_sv["graybox"] = [e.n_support_ for e in graybox.residual_.estimators_]
    decoupled = {}
    for name in ("ls", "krr", "svr", "gp"):
        decoupled[name] = {}
        for d in DOFS:
            x = train[VELOCITY_COLUMNS[d]].to_numpy()[::4, None]
            y = train["d_" + TAU_COLUMNS[d][4:]].to_numpy()[::4]
            decoupled[name][d] = make_estimator(name, seed=0, gp_max_samples=300).fit(x, y)

    t_ns, seg = test["t_ns"].to_numpy(), test["segment"].to_numpy()
    nu = test[vel].to_numpy()
    tau = test[[TAU_COLUMNS[d] for d in DOFS]].to_numpy()
    rpm = test[RPM].to_numpy()
    ranges = {d: table_range(nu[:, j]) for j, d in enumerate(DOFS)}
    M = plant.mass_matrix()
    horizons, outages = [1.0, 5.0, 10.0], [10.0, 30.0, 60.0]
    rows = []

    blas = threadpool_limits(1, user_api="blas") if mode == "stage" else contextlib.nullcontext()
    blas.__enter__()
    t0 = clock()
    for name, est in coupled.items():  # each coupled model: free runs + horizon windows in one batch
        a = clock()
        run, _ = run_model(name, CoupledDynamics(est), t_ns, nu, rpm, DOFS, horizons, segment=seg)
        b = clock()
        rows.append((f"coupled {name}", b[0] - a[0], b[1] - a[1], f"{run.metrics['u']['r2']:.3f}"))
    a = clock()
    run, _ = run_model("graybox", CoupledDynamics(graybox, fast=mode == "stage"), t_ns, nu, np.hstack([tau, rpm]),
                       DOFS, horizons, segment=seg)
    b = clock()
    rows.append(("coupled graybox", b[0] - a[0], b[1] - a[1], f"{run.metrics['u']['r2']:.3f}"))
    a = clock()  # all decoupled models, the GP's band members too, in one batch (one call per RK4 stage)
    fs, batch = {}, {}
    for name, models in decoupled.items():
        fs[name] = DecoupledDynamics(M, DOFS, damping_tables(models, ranges), coriolis_force)
        band = (DecoupledDynamics(M, DOFS, band_tables(models, ranges, 32), coriolis_force)
                if name == "gp" else None)
        batch[name] = (fs[name], band)
    done = run_models(batch, t_ns, nu, tau, DOFS, horizons, segment=seg, band_members=32)
    b = clock()
    rows.append(("decoupled " + ", ".join(decoupled) + " (+ GP band 32), one batch", b[0] - a[0], b[1] - a[1],
                 " / ".join(f"{done[n][0].metrics['u']['r2']:.3f}" for n in decoupled)))
    a = clock()
    bridge_outages(fs, t_ns, nu, tau, test["yaw_rad"].to_numpy(), DOFS, outages, segment=seg)
    b = clock()
    rows.append(("bridging (all decoupled)", b[0] - a[0], b[1] - a[1], None))
    total = (b[0] - t0[0], b[1] - t0[1])
    blas.__exit__(None, None, None)

    # one SVR predict over the rows the three coupled free runs + horizons evaluated
    n_rows = 3 * 4 * (2 * len(t_ns))  # three models, 4 stages, free run + horizons (~1 row each per step)
    Xq = np.resize(np.hstack([nu, rpm]), (n_rows, 6))
    a = clock()
    for est in coupled.values():
        est.predict(Xq[: n_rows // 3])
    b = clock()
    predict = (b[0] - a[0], b[1] - a[1])

    print(f"mode {mode}; trial {trial_s:g} s at 20 Hz ({len(t_ns)} samples, one 5-s gap), "
          f"SVRs trained on {train_s:g} s; support vectors per output {n_sv}")
    print("| what | wall s | CPU s | free-run u R² |")
    print("| --- | ---: | ---: | ---: |")
    for what, wall, cpu, r2 in rows:
        print(f"| {what} | {wall:.2f} | {cpu:.2f} | {r2 or ''} |")
    print(f"| **all free runs, horizons, bridging** | **{total[0]:.2f}** | **{total[1]:.2f}** | |")
    print(f"| one SVR predict per coupled model over the same rows ({n_rows} rows in all) | {predict[0]:.2f} | "
          f"{predict[1]:.2f} | |")
    print(f"ratio (all / one predict over the same rows): wall {total[0] / predict[0]:.1f}, "
          f"CPU {total[1] / predict[1]:.1f}")


if __name__ == "__main__":
    main()
