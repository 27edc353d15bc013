"""The default (fast) search for 6-input WDSE-SVR (8 hyperparameters) against a random search 100x its budget.

The paper's grid (5 candidates x 8 hyperparameters = 390,625 candidates x 3 blocked folds = 1,171,875 SVR fits) is
too large to run, so the reference is a random search with 100 times the fast search's budget in SVR fits,
log-uniform over the grid's span (gamma 1e-3..10 on standardized inputs, C 0.1..1000 x SD(y), epsilon
1e-3..0.3 x SD(y)), seeded. The fast search runs as ``pipeline.studies.coupled.tune`` runs it: RBF, then
2-weights warm-started from RBF's optimum, then WDSE warm-started from 2-weights' (``max_evals`` 30 each, the
default); the table reports WDSE. Every score is the same blocked 3-fold CV mean R² on the same rows.

Problems (inputs ``[u v r n1 n2 n3]``, ``n`` rows 0.5 s apart, one per source x seed x output):

* ``synthetic``: :func:`pipeline.sim.synthetic.synthetic_frame` (coupled damping beyond the explicit models, thrust lost
  to inflow), measurement noise 10 % of each signal's SD;
* ``sim``: a trial of the project's simulator (``pipeline.sim``, DAGON, propeller inflow loss on), truth at 200 Hz
  taken every 0.5 s, velocities and accelerations with 5 % noise (rpm as logged, exact).

The reference searches are slow (~150 s each on one core) and depend only on the data, so they are cached in
``--cache`` (JSON, keyed by problem and budget).

Usage: python bench/search.py [--n 200] [--seeds 0 1 2] [--outputs udot_mps2 vdot_mps2 rdot_radps2]
                              [--sources synthetic sim] [--jobs 2] [--cache /tmp/auvid_search_reference.json]
                              [--model-share 0.6] [--reference-only]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from joblib import Parallel, delayed

from pipeline.evaluate import blocked_folds
from pipeline.models.search import (
    C_GRID,
    EPSILON_GRID,
    GAMMA_GRID,
    cv_score,
    fast_search,
    paper_grid,
)
from pipeline.sim import DAGON_INFLOW_LOSS, generate_trial, load_example_vehicle, load_truth
from pipeline.sim.synthetic import synthetic_frame

INPUTS = ["u_mps", "v_mps", "r_radps", "n1_rpm", "n2_rpm", "n3_rpm"]
N_FOLDS = 3
MAX_EVALS = 30  # CoupledParams.max_evals default


def problem(source: str, output: str, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` rows 0.5 s apart of one trial (see the module docstring)."""
    if source == "synthetic":
        frame = synthetic_frame(n, seed=seed, noise=0.1, split="tuning")
        return frame[INPUTS].to_numpy(float), frame[output].to_numpy(float)
    truth = dataclasses.replace(load_truth(), inflow_loss=DAGON_INFLOW_LOSS)
    table = generate_trial(load_example_vehicle(), duration_s=0.5 * n + 1.0, seed=seed, truth=truth).truth
    rows = table.iloc[np.arange(n) * 100]  # 200 Hz -> 2 Hz
    rng = np.random.default_rng(1000 + seed)
    X = rows[INPUTS].to_numpy(float, copy=True)
    y = rows[output].to_numpy(float)
    X[:, :3] += 0.05 * X[:, :3].std(axis=0) * rng.normal(size=(n, 3))
    y = y + 0.05 * y.std() * rng.normal(size=n)
    return X, y


def _random_candidate(rng: np.random.Generator, d: int, y_sd: float) -> dict[str, object]:
    lg = np.log10
    return {"gammas": (10 ** rng.uniform(lg(GAMMA_GRID[0]), lg(GAMMA_GRID[-1]), d)).tolist(),
            "C": float(y_sd * 10 ** rng.uniform(lg(C_GRID[0]), lg(C_GRID[-1]))),
            "epsilon": float(y_sd * 10 ** rng.uniform(lg(EPSILON_GRID[0]), lg(EPSILON_GRID[-1])))}


def random_reference(X: np.ndarray, y: np.ndarray, n_fits: int, seed: int, n_jobs: int) -> dict[str, object]:
    """Best of ``n_fits // N_FOLDS`` log-uniform candidates over the paper grid's span."""
    rng = np.random.default_rng(seed)
    cands = [_random_candidate(rng, X.shape[1], float(np.std(y))) for _ in range(n_fits // N_FOLDS)]
    folds = blocked_folds(len(X), N_FOLDS)
    t0 = time.perf_counter()
    scores = Parallel(n_jobs=n_jobs, batch_size=8)(delayed(cv_score)("wdse_svr", c, X, y, folds) for c in cands)
    best = int(np.argmax(scores))
    return {"best_score": float(scores[best]), "best_params": cands[best], "n_fits": len(cands) * N_FOLDS,
            "elapsed_s": time.perf_counter() - t0}


def chained_fast(X: np.ndarray, y: np.ndarray, seed: int = 0, **kw: object) -> tuple[object, list[object]]:
    """RBF -> 2-weights -> WDSE, each warm-started from the previous optimum (as ``tune`` does)."""
    prev, chain = None, []
    for model in ("rbf_svr", "two_weights_svr", "wdse_svr"):
        res = fast_search(model, X, y, n_folds=N_FOLDS, max_evals=MAX_EVALS, seed=seed, warm_start=prev, **kw)
        chain.append(res)
        prev = res.best_params
    return chain[-1], chain


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--outputs", nargs="+", default=["udot_mps2", "vdot_mps2", "rdot_radps2"])
    ap.add_argument("--sources", nargs="+", default=["synthetic", "sim"])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/auvid_search_reference.json"))
    ap.add_argument("--model-share", type=float, default=None, help="fast_search model_share (default: its own)")
    ap.add_argument("--reference-only", action="store_true", help="fill the cache, skip the fast search")
    args = ap.parse_args()
    cache = json.loads(args.cache.read_text()) if args.cache.exists() else {}
    grid_fits = int(np.prod([len(v) for v in paper_grid("wdse_svr", len(INPUTS)).values()])) * N_FOLDS
    ref_fits = 100 * MAX_EVALS * N_FOLDS
    rows = []
    t_start = time.perf_counter()
    for source in args.sources:
        for seed in args.seeds:
            for output in args.outputs:
                X, y = problem(source, output, args.n, seed)
                key = f"{source}/{output}/n{args.n}/seed{seed}/fits{ref_fits}"
                if key not in cache:
                    cache[key] = random_reference(X, y, ref_fits, seed, args.jobs)
                    args.cache.write_text(json.dumps(cache, indent=1))
                    print(f"reference {key}: R2 {cache[key]['best_score']:.4f} in {cache[key]['elapsed_s']:.0f} s",
                          flush=True)
                if args.reference_only:
                    continue
                kw = {} if args.model_share is None else {"model_share": args.model_share}
                fast, chain = chained_fast(X, y, **kw)
                rows.append((source, seed, output, fast, chain, cache[key]))
    if args.reference_only:
        return
    print(f"WDSE-SVR, 6 inputs {' '.join(INPUTS)}, 8 hyperparameters; n = {args.n} rows, blocked {N_FOLDS}-fold CV; "
          f"paper grid {grid_fits:,} fits (1 % = {grid_fits // 100:,}); reference: random search of {ref_fits:,} "
          f"fits (100 x the fast budget); total {time.perf_counter() - t_start:.0f} s")
    print("| source | seed | output | RBF R² | 2-weights R² | WDSE fast R² | WDSE fits | % of grid fits | "
          "random 100x R² | fast − random | WDSE moved from warm start |")
    print("| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |")
    deltas = []
    for source, seed, output, fast, chain, ref in rows:
        delta = fast.best_score - ref["best_score"]
        deltas.append(delta)
        moved = "no: " + fast.note if fast.warm_start_kept else "yes"
        print(f"| {source} | {seed} | {output} | {chain[0].best_score:.4f} | {chain[1].best_score:.4f} | "
              f"{fast.best_score:.4f} | {fast.n_fits} | {100 * fast.n_fits / grid_fits:.4f} % | "
              f"{ref['best_score']:.4f} | {delta:+.4f} | {moved} |")
    d = np.array(deltas)
    print(f"fast − random: mean {d.mean():+.4f}, min {d.min():+.4f}, fast >= random in {(d >= 0).sum()}/{d.size}")


if __name__ == "__main__":
    main()
