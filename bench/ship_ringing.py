"""A ship's towing-tank zig-zags with a narrow-band disturbance on the measured surge (a carriage or shaft vibration),
from the raw tables to trained SVRs with the defaults, scored against the simulator's TRUE accelerations (issue 34).

Per seed S: training zig-zag z1 (simulator seed 10 S + 1) and the unseen zig-zag z2 (10 S + 2), 150 s each, written
by ``pipeline.sim.tank`` as the carriage's cp1252 whitespace tables, with a ``--ring-mps`` (default 0.02 m/s)
disturbance at ``--ring-hz`` (default 2 Hz) on the measured surge. The vehicle config is the ship.yaml of
docs/user-guide.md §9; the params hold only what a user must set for this ship: ``features.test_trials: [z2]`` and
``coupled.inputs`` / ``actuator_inputs`` / ``models`` (the three SVRs; the rudder is an input the defaults cannot
guess); everything else is the code's default unless ``--set KEY=YAML`` overrides it (e.g. ``--set
differentiate.disturbances=keep``). ``auvid run --to train`` then runs in-process.

Printed per seed: each target's R² against the truth over z2's feature rows; the **ceiling** (the true model at
the same estimated inputs: u, v, r from the smoother, the logged propeller speed and rudder, against the same
truth); each model's final R² against the truth and its gap to the ceiling; and the sentences the report shows: the
disturbances the differentiate stage removed and the derive stage's spectral check. ``--quick`` adds the guide's
quick-pass keys (3 folds, 6 candidates, 300 tuning rows). The guide's rudder has a lift model of the simulator's rudder
force (``control_surfaces[].lift``), so that tau carries it; ``--no-lift`` drops it (compare with ``--set
'coupled.models=[gertler_hagen, ...]'``).

    nice python bench/ship_ringing.py 0 1 2
    nice python bench/ship_ringing.py --set differentiate.disturbances=keep 0
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from pipeline import layout, store
from pipeline.cli import main as auvid
from pipeline.config import load_params
from pipeline.estimation.spectral import report_path
from pipeline.layout import MODELS, estimation_report_path
from pipeline.models.card import load_model
from pipeline.sim.tank import nudot, simulate_zigzag
from pipeline.studies.coupled import model_inputs
from pipeline.tableio import read_parquet
from tests.cli.guide_helpers import guide_block

GUIDE = "Walkthrough: a ship model in a towing tank"
OUTPUTS = ("udot_mps2", "vdot_mps2", "rdot_radps2")
SVRS = ("rbf_svr", "two_weights_svr", "wdse_svr")


def r2(truth: np.ndarray, estimate: np.ndarray) -> float:
    return float(1 - np.mean((estimate - truth) ** 2) / np.var(truth))


def ship_params(overrides: dict[str, object], quick: bool = False) -> dict:
    """The params a user must write for the guide's ship, and ``overrides`` (dotted keys)."""
    params: dict = {"features": {"test_trials": ["z2"]},
                    "coupled": {"inputs": ["u_mps", "v_mps", "r_radps", "rudder_rad", "n_prop_rpm"],
                                "actuator_inputs": ["rudder_rad", "n_prop_rpm"], "models": list(SVRS)}}
    if quick:
        params["coupled"].update(folds=3, max_evals=6, max_samples=300)
    for key, value in overrides.items():
        *path, last = key.split(".")
        node = params
        for part in path:
            node = node.setdefault(part, {})
        node[last] = value
    return params


def write_campaign(root: Path, seed: int, ring_mps: float, ring_hz: float, duration_s: float,
                   params: dict, lift: bool = True) -> dict[str, np.ndarray]:
    """The raw tables of z1 and z2 under ``root/tank``, ship.yaml and params.yaml; the truths per trial."""
    truths = {}
    for k, trial in ((1, "z1"), (2, "z2")):
        text, truths[trial] = simulate_zigzag(10 * seed + k, duration_s, ring_mps=ring_mps, ring_hz=ring_hz)
        (root / "tank" / trial).mkdir(parents=True)
        (root / "tank" / trial / "run01.dat").write_bytes(text.encode("cp1252"))
    vehicle = guide_block(GUIDE, "yaml", "# ship.yaml")
    # the guide's rudder has the simulator's force as its lift model: 40 delta u|u| N at 1 m aft = 1/2 rho A C_La
    # with A C_La = 0.08 m^2; --no-lift drops it (the rudder an input of the learned models only)
    plain, lifted = re.subn(r",\n\s+lift: \{[^}]*\}\}", "}", vehicle)
    assert lifted == 1, "the guide's ship.yaml has no rudder lift model"
    if not lift:
        vehicle = plain
    (root / "ship.yaml").write_text(vehicle)
    (root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    return truths


def truth_at(run: Path, trial: str, t_ns: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """The simulator's rows at the feature rows' stamps (the table's rows are 50 ms apart from its first)."""
    first = int(read_parquet(layout.stream_path(run, trial, "tank"))[0].column("t_ns")[0].as_py())
    return truth[np.round((t_ns - first) / 5e7).astype(int)]


def score(run: Path, truths: dict[str, np.ndarray]) -> dict:
    """Targets, ceiling and each SVR against the truth on z2, and the sentences the report shows."""
    params = load_params(run.parent / "params.yaml")
    test = store.load(run, split="test").sort_values("t_ns")
    truth = truth_at(run, "z2", test["t_ns"].to_numpy(), truths["z2"])
    nu = np.zeros((len(test), 6))
    nu[:, 0], nu[:, 1], nu[:, 5] = test["u_mps"], test["v_mps"], test["r_radps"]
    ceiling = nudot(nu, test["n_prop_rpm"].to_numpy(), test["rudder_rad"].to_numpy())[:, [0, 1, 5]]
    out = {"targets": {o: r2(truth[:, j], test[o].to_numpy()) for j, o in enumerate(OUTPUTS)},
           "ceiling": {o: r2(truth[:, j], ceiling[:, j]) for j, o in enumerate(OUTPUTS)}, "models": {}}
    for model in params.coupled.models:
        estimator, _ = load_model(run / MODELS / "coupled" / f"{model}.joblib")
        predicted = estimator.predict(test[model_inputs(model, params.coupled)].to_numpy(float))
        out["models"][model] = {o: r2(truth[:, j], predicted[:, j]) for j, o in enumerate(OUTPUTS)}
    out["check"] = [w["text"] for t in ("z1", "z2")
                    for w in json.loads(report_path(run, t).read_text())["warnings"]]
    out["removed"] = [f"{t}: {d['text']}" for t in ("z1", "z2")
                      for d in json.loads(estimation_report_path(run, t).read_text()).get("disturbances", [])]
    return out


def one_seed(seed: int, args: argparse.Namespace, overrides: dict[str, object]) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        truths = write_campaign(root, seed, args.ring_mps, args.ring_hz, args.duration,
                                ship_params(overrides, args.quick), args.lift)
        run = root / "runs"
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            code = auvid(["run", "--root", str(run), "--vehicle", str(root / "ship.yaml"), "--params",
                          str(root / "params.yaml"), "--to", "train", str(root / "tank/z1"), str(root / "tank/z2")])
        if code not in (0, 1):
            raise SystemExit(f"seed {seed}: auvid run exited {code}")
        out = score(run, truths)
        out["seconds"] = time.perf_counter() - t0
        return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("seeds", nargs="*", type=int, default=[0])
    parser.add_argument("--ring-mps", type=float, default=0.02)
    parser.add_argument("--ring-hz", type=float, default=2.0)
    parser.add_argument("--duration", type=float, default=150.0)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--no-lift", dest="lift", action="store_false",
                        help="the rudder without the lift model the guide's ship.yaml gives it")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=YAML")
    args = parser.parse_args(argv)
    overrides = {k: yaml.safe_load(v) for k, v in (s.split("=", 1) for s in args.set)}
    results = []
    for seed in args.seeds:
        res = one_seed(seed, args, overrides)
        results.append(res)
        print(f"seed {seed} ({res['seconds']:.0f} s): targets "
              + " ".join(f"{v:.3f}" for v in res["targets"].values())
              + ", ceiling " + " ".join(f"{v:.3f}" for v in res["ceiling"].values()), flush=True)
        for model, scores in res["models"].items():
            gaps = [res["ceiling"][o] - scores[o] for o in OUTPUTS]
            print(f"  {model:16s} " + " ".join(f"{scores[o]:.3f}" for o in OUTPUTS)
                  + "  below the ceiling " + " ".join(f"{g:.3f}" for g in gaps), flush=True)
        for text in res["check"]:
            print(f"  check: {text}")
        for text in res["removed"]:
            print(f"  removed: {text}")
    if len(results) > 1:
        gaps = np.array([[[r["ceiling"][o] - r["models"][m][o] for o in OUTPUTS] for m in results[0]["models"]]
                         for r in results])
        print("gap to the ceiling, mean over seeds (rows: models; u̇ v̇ ṙ):\n" + str(np.round(gaps.mean(0), 3)))
        print("worst seed:\n" + str(np.round(gaps.max(0), 3)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
