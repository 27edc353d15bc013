"""dvc.yaml, checked structurally without DVC installed (a real `dvc repro` check: bench/dvc_repro.sh)."""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from pipeline import layout
from pipeline.config import Params, load_params
from pipeline.models.card import card_path
from stages.common import STAGE_ORDER
from tests.report.test_report import check_headline_against_metrics, run_dir, study_dir  # noqa: F401  (fixtures: a run with the stages' study files)

REPO = Path(__file__).resolve().parents[2]
DVC = REPO / "dvc.yaml"


def _interpolate(value: Any, ctx: dict[str, Any]) -> Any:
    if isinstance(value, str):
        whole = re.fullmatch(r"\$\{(\w+)\}", value)
        if whole:
            return ctx[whole.group(1)]
        return re.sub(r"\$\{(\w+)\}", lambda m: str(ctx[m.group(1)]), value)
    if isinstance(value, list):
        return [_interpolate(v, ctx) for v in value]
    if isinstance(value, dict):
        return {_interpolate(k, ctx): _interpolate(v, ctx) for k, v in value.items()}
    return value


def _entries(items: list[Any]) -> list[str]:
    """Paths of a deps/outs/metrics/plots list (entries are a path or {path: options})."""
    return [next(iter(i)) if isinstance(i, dict) else i for i in items or []]


def expanded_stages() -> list[tuple[str, str, dict[str, Any]]]:
    """(stage name, expanded name, definition) in file order, with vars and foreach resolved."""
    doc = yaml.safe_load(DVC.read_text())
    ctx: dict[str, Any] = {}
    for entry in doc.get("vars", []):
        assert isinstance(entry, dict), "vars from files are not used here"
        ctx.update(entry)
    out = []
    for name, stage in doc["stages"].items():
        if "foreach" in stage:
            for item in _interpolate(stage["foreach"], ctx):
                out.append((name, f"{name}@{item}", _interpolate(stage["do"], {**ctx, "item": item})))
        else:
            out.append((name, name, _interpolate(stage, ctx)))
    return out


def _overlaps(a: str, b: str) -> bool:
    pa, pb = Path(a), Path(b)
    return pa == pb or pa in pb.parents or pb in pa.parents


def test_no_flow_style_templated_lists() -> None:
    for number, line in enumerate(DVC.read_text().splitlines(), 1):
        line = line.split("#", 1)[0]
        assert not re.search(r"\[[^\]]*\$\{", line), f"dvc.yaml:{number}: flow-style templated list: {line!r}"


def _modules(cmd: str) -> list[str]:
    return re.findall(r"python -m stages\.(\w+)\b", cmd)


def test_every_stage_of_the_dag_is_there_in_order() -> None:
    run = [m for _, _, stage in expanded_stages() for m in _modules(stage["cmd"])]
    assert [m for m in run if m in STAGE_ORDER] == list(STAGE_ORDER)


def test_each_stage_runs_existing_modules_that_are_its_deps() -> None:
    """A DVC stage runs its own module (``train`` runs ``tune`` first: they write into the same directories)."""
    for name, full, stage in expanded_stages():
        modules = _modules(stage["cmd"])
        parts = [p.strip() for p in stage["cmd"].split("&&")]
        assert modules and len(modules) == len(parts), f"{full}: cmd must be `python -m stages.<name> ...`"
        assert name in modules, f"{full}: does not run stages.{name}"
        for module in modules:
            assert importlib.util.find_spec(f"stages.{module}") is not None, f"{full}: no module stages/{module}.py"
            assert f"stages/{module}.py" in _entries(stage.get("deps")), f"{full}: stages/{module}.py is not a dep"


def test_params_keys_exist_in_the_schema_and_in_params_yaml() -> None:
    params_doc = yaml.safe_load((REPO / "params.yaml").read_text())
    load_params(REPO / "params.yaml")  # validates against the Params schema
    sections = Params.model_fields
    for _, full, stage in expanded_stages():
        for key in stage.get("params", []):
            assert isinstance(key, str), f"{full}: params from other files are not used"
            section, _, field = key.partition(".")
            assert section in sections, f"{full}: params key {key!r} is not a Params section"
            if field:
                assert field in sections[section].annotation.model_fields, f"{full}: no params key {key!r}"
                assert field in params_doc[section], f"{full}: {key!r} missing from params.yaml"
            else:
                assert section in params_doc, f"{full}: section {section!r} missing from params.yaml"


def test_params_yaml_holds_only_what_the_example_changes() -> None:
    """The repository's params.yaml is the example's: the keys ``auvid demo`` writes (none at its default), so a
    benchmark or a DVC run from the repository runs the code's defaults wherever the example does not differ."""
    from pipeline.demo import demo_params

    doc = yaml.safe_load((REPO / "params.yaml").read_text())
    trials = ["trial01", "trial02", "trial03"]
    assert doc["features"]["test_trials"] == trials[-1:]
    example = demo_params(trials)
    assert {s: v for s, v in doc.items() if v} == example
    defaults = Params().model_dump()
    for section, values in doc.items():
        for key, value in values.items():
            assert value != defaults[section][key], f"params.yaml: {section}.{key} is the default ({value!r})"


def test_deps_are_produced_upstream_or_tracked_inputs() -> None:
    produced: dict[str, str] = {}
    tracked = set(subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True,
                                 check=True).stdout.split())
    for _, full, stage in expanded_stages():
        outs = _entries(stage.get("outs")) + _entries(stage.get("metrics")) + _entries(stage.get("plots"))
        for dep in _entries(stage.get("deps")):
            if dep.startswith(("data/", "reports/")):
                producers = [p for out, p in produced.items() if _overlaps(out, dep)]
                assert producers, f"{full}: dep {dep} is produced by no earlier stage"
            else:
                exists = (REPO / dep).exists() or any(t == dep or t.startswith(f"{dep.rstrip('/')}/") for t in tracked)
                assert exists, f"{full}: dep {dep} is not in the repository"
        for out in outs:
            clash = [p for o, p in produced.items() if _overlaps(o, out)]
            assert not clash, f"{full}: out {out} overlaps the outs of {clash}"
            produced[out] = full


def test_metrics_plots_and_dvcignore() -> None:
    stages = {full: s for _, full, s in expanded_stages()}
    assert _entries(stages["report"]["metrics"]) == ["reports/headline.json"]
    assert len(_entries(stages["report"]["plots"])) >= 1
    ignore = (REPO / ".dvcignore").read_text().split()
    assert "__pycache__" in ignore


# Trials and models a user might have: none of them is the example's, and there are more models than one.
USER_TRIALS = ["basin_a", "sea_b"]
USER_COUPLED = ["rbf_svr", "gertler_hagen"]
USER_DECOUPLED = ["ls", "svr"]


def _outs_of(stages: dict[str, dict[str, Any]]) -> dict[str, str]:
    return {out: full for full, s in stages.items()
            for out in _entries(s.get("outs")) + _entries(s.get("metrics")) + _entries(s.get("plots"))}


def _files_of_a_run(trials: list[str], coupled: list[str], decoupled: list[str], dofs: list[str]) -> dict[str, str]:
    """Files (run-relative) each stage writes for these trials and model lists, by the stages' own path helpers."""
    from pipeline import layout
    from stages.decoupled import evaluation_dir, models_dir
    from stages.tune import hyperparameters_path

    root = Path(".")
    files: dict[str, str] = {}
    for t in trials:
        files[layout.ingest_report_path(root, t).as_posix()] = "ingest"
        files[layout.synced_path(root, t).as_posix()] = "sync"
        files[layout.kinematics_path(root, t).as_posix()] = "differentiate"
        files[layout.estimation_report_path(root, t).as_posix()] = "differentiate"
        files[layout.derived_path(root, t).as_posix()] = "derive"
        files[f"{layout.SIMULATION}/{t}/free_run.json"] = "simulate"
    files[f"{layout.features_dir(root).as_posix()}/part-0.parquet"] = "features"
    files[hyperparameters_path(root).as_posix()] = "train"  # stages.tune, run by the `train` DVC stage
    files[f"{layout.EVALUATION}/coupled/table2.json"] = "train"
    for m in coupled:
        model = Path(layout.MODELS) / "coupled" / f"{m}.joblib"
        files[model.as_posix()] = files[card_path(model).as_posix()] = "train"
    files[f"{layout.EVALUATION}/coupled/table3.json"] = "train"
    for d in dofs:
        for m in decoupled:
            files[(models_dir(root) / f"{d}_{m}.joblib").as_posix()] = "decoupled"
    files[(evaluation_dir(root) / "metrics.json").as_posix()] = "decoupled"
    files["reports/report.html"] = "report"
    files["reports/headline.json"] = "report"
    return files


def test_the_dag_covers_any_trials_and_any_model_lists() -> None:
    """With trials basin_a, sea_b and two coupled models, every file a stage writes lies in one of that stage's
    outs, and the deps of the stage after it hold it: the DAG does not split, nothing is written untracked."""
    stages = {full: s for _, full, s in expanded_stages()}
    outs = _outs_of(stages)
    files = _files_of_a_run(USER_TRIALS, USER_COUPLED, USER_DECOUPLED, ["u", "v", "r"])
    for file, writer in files.items():
        owners = [stage for out, stage in outs.items() if _overlaps(out, file)]
        assert owners == [writer], f"{file} (written by {writer}) lies in the outs of {owners or 'no stage'}"
    readers = {"sync": "ingest", "differentiate": "sync", "derive": "differentiate", "features": "derive",
               "train": "features", "decoupled": "features", "simulate": "train", "report": "simulate"}
    for reader, writer in readers.items():
        deps = _entries(stages[reader]["deps"])
        held = [f for f, w in files.items() if w == writer and any(_overlaps(d, f) for d in deps)]
        assert held, f"{reader} depends on nothing that {writer} writes (deps: {deps})"


def test_no_trial_or_model_names_in_dvc_yaml() -> None:
    params = load_params(REPO / "params.yaml")
    names = {*params.coupled.models, *params.decoupled.models, *params.features.test_trials,
             *(f"trial{i:02d}" for i in range(1, 10))}
    text = "\n".join(line.split("#", 1)[0] for line in DVC.read_text().splitlines())
    assert not re.search(r"trial\d", text), "dvc.yaml names a trial"
    doc = yaml.safe_load(DVC.read_text())
    assert "foreach" not in text and "trials" not in str(doc.get("vars")), "stages are not driven by a trial list"
    for _, full, stage in expanded_stages():
        for path in _entries(stage.get("deps")) + list(_outs_of({full: stage})):
            parts = {p.removesuffix(".joblib").removesuffix(".card") for p in Path(path).with_suffix("").parts}
            assert not parts & names, f"{full}: {path} names a trial or model of params.yaml"


def test_metrics_and_plots_are_committed_not_ignored() -> None:
    """DVC keeps cache: false files out of its cache: git must carry them, or `dvc metrics diff` has nothing."""
    stages = {full: s for _, full, s in expanded_stages()}
    report = stages["report"]
    small = report["metrics"] + report["plots"]
    for entry in small:
        path, options = next(iter(entry.items()))
        assert options.get("cache") is False, f"{path}: metrics and plots go to git, not the DVC cache"
        ignored = subprocess.run(["git", "check-ignore", "-q", "--no-index", path], cwd=REPO).returncode == 0
        assert not ignored, f"{path} is git-ignored: `dvc metrics diff` / `dvc plots diff` would find nothing"
    for path in _entries(report["outs"]):
        ignored = subprocess.run(["git", "check-ignore", "-q", "--no-index", path], cwd=REPO).returncode == 0
        assert ignored, f"{path} is a cached out; git must ignore it"


def test_headline_metrics_are_a_handful_with_known_values() -> None:
    from stages.report import headline

    coupled = {"rbf_svr": {"udot_mps2": {"final_r2": 0.7, "cv_test_r2": 0.9}, "rdot_radps2": {"final_r2": 0.2}},
               "gertler_hagen": {"udot_mps2": {"final_r2": 0.8}, "rdot_radps2": {"final_r2": float("nan")}}}
    decoupled = {"lineage": {"trials": ["basin_a"]},
                 "results": {"u": {"ls": {"cv": {"test_mae_mean": 2.0}}, "svr": {"cv": {"test_mae_mean": 1.5}}}}}
    simulation = {"sea_b": {"free_run": [
        {"model": "ls", "status": "ok", "metrics": {"u": {"mae": 0.03, "r2": 0.9}}},
        {"model": "coupled_rbf_svr", "status": "diverged", "metrics": {"u": {"mae": 0.001}}},
        {"model": "svr", "status": "ok", "metrics": {"u": {"mae": 0.02}}}]}}
    doc = headline(coupled, decoupled, simulation)
    # RBF-SVR's free run diverged: left out of "best" on every output, so ṙ has none (Gertler–Hagen's is NaN)
    assert doc == {"coupled_final_r2": {"udot_mps2": {"best": 0.8, "model": "gertler_hagen"}},
                   "damping_mae": {"u": {"best_mae": 1.5, "model": "svr", "ls_mae": 2.0, "vs_ls": 0.75}},
                   "free_run_mae": {"u": {"best": 0.02, "model": "svr"}}}
    assert headline(None, None, None) == {}


# ------------------------------------------------------------------------- a real DVC project (where DVC is there)

def _project(tmp: Path, coupled: tuple[str, ...] = ("rbf_svr", "gertler_hagen"),
             decoupled: tuple[str, ...] = ("ls", "svr"), duration_s: float = 60.0) -> Path:
    """A DVC project as the user guide describes it: the code, logs basin_a and sea_b in data/raw/ (`dvc add`),
    the example stage deleted, two coupled models; sized to run in about a minute."""
    from pipeline.sim import example

    proj = tmp / "proj"
    for tree in ("pipeline", "stages"):
        shutil.copytree(REPO / tree, proj / tree, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for name in (".dvcignore", ".gitignore", "params.yaml"):
        shutil.copy(REPO / name, proj / name)
    doc = yaml.safe_load(DVC.read_text())
    del doc["stages"]["example"]
    (proj / "dvc.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    written = example(tmp / "gen", fmt="mcap", duration_s=duration_s, seed=1, n_trials=2)
    (proj / "data" / "raw").mkdir(parents=True)
    for log, name in zip(sorted(written.trials, key=str), ("basin_a", "sea_b"), strict=True):
        shutil.copy(log, proj / "data" / "raw" / f"{name}{Path(log).suffix}")
    params = yaml.safe_load((proj / "params.yaml").read_text())
    params["features"]["test_trials"] = ["sea_b"]
    params["coupled"].update(models=list(coupled), folds=2, max_evals=4, max_samples=300, tuning="split")
    params["decoupled"].update(models=list(decoupled), folds=2, curve_points=2, max_samples=300)
    params["simulate"].update(horizons_s=[1.0], outage_windows_s=[10.0], band_samples=2)
    (proj / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    load_params(proj / "params.yaml")
    return proj


def _ran(log: str) -> set[str]:
    return set(re.findall(r"Running stage '([\w@.-]+)'", log))


def _dvc_or_skip() -> str:
    dvc = shutil.which("dvc") or shutil.which("dvc", path=str(Path(sys.executable).parent))
    if dvc is None:
        pytest.skip("dvc is not installed (pip install -e '.[dvc]'): the real DVC checks did not run; "
                    "the structural checks of dvc.yaml and .gitignore did")
    return dvc


def _dvc_env() -> dict[str, str]:
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
           "DVC_NO_ANALYTICS": "1", "AUVID_JOBS": "1", "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t",
           "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@t"}
    env.pop("AUVID_SCHEDULER", None)
    return env


def _shell(cwd: Path, env: dict[str, str]) -> Any:
    def sh(*cmd: str) -> str:
        done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
        assert done.returncode == 0, f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stdout}\n{done.stderr}"
        return done.stdout + done.stderr
    return sh


def test_dvc_repro_with_the_users_trials(tmp_path: Path) -> None:
    """Reproduces, then does nothing, then reruns only what is downstream of a changed param; `dvc metrics diff`
    shows the change. Needs DVC (`pip install -e '.[dvc]'`): about a minute."""
    dvc = _dvc_or_skip()
    proj = _project(tmp_path)
    env = _dvc_env()
    sh = _shell(proj, env)

    sh("git", "init", "-q")
    sh(dvc, "init", "-q")
    sh(dvc, "add", "data/raw")
    sh("git", "add", ".")
    sh("git", "commit", "-qm", "project")
    first = _ran(sh(dvc, "repro"))
    every = {"ingest", "sync", "differentiate", "derive", "features", "train", "decoupled", "simulate", "report"}
    assert first == every
    assert (proj / "data/synced/basin_a.parquet").is_file() and (proj / "data/synced/sea_b.parquet").is_file()
    assert (proj / "data/models/coupled/gertler_hagen.joblib").is_file()
    assert check_headline_against_metrics(proj) >= 2 * 3  # the report's headline box = reports/metrics.json
    shown = json.loads(subprocess.run([dvc, "plots", "show", "--json"], cwd=proj, env=env, capture_output=True,
                                      text=True, check=True).stdout)  # stdout only: sh() adds stderr
    shown = {Path(k).stem: v for k, v in shown.get("data", shown).items()}
    for name in MODEL_PLOTS:  # the model plots, with rows from this run's models
        assert shown[name][0]["content"]["data"]["values"], name
    sh("git", "add", "dvc.lock", "reports/headline.json", "reports/plots")
    sh("git", "commit", "-qm", "first run")
    assert sh("git", "status", "--porcelain").strip() == "", "dvc repro left files git neither tracks nor ignores"
    assert _ran(sh(dvc, "repro")) == set()

    params = yaml.safe_load((proj / "params.yaml").read_text())
    params["coupled"]["tuning"] = "nested"  # other hyperparameters, so other scores on the unseen trial
    (proj / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    assert _ran(sh(dvc, "repro")) == {"train", "simulate", "report"}
    diff = json.loads(sh(dvc, "metrics", "diff", "--json"))
    changed = diff.get("diff", diff).get("reports/headline.json", {})
    # a changed score, or a best model that appears or goes (the headline leaves out models whose train R² is
    # below 0 or whose free run failed)
    assert any(k.startswith("coupled_final_r2.") and (v.get("diff") or v.get("old") != v.get("new"))
               for k, v in changed.items()), changed
    plots = json.loads(subprocess.run([dvc, "plots", "diff", "HEAD", "--json"], cwd=proj, env=env, check=True,
                                      capture_output=True, text=True).stdout)
    plots = {Path(k).stem: v for k, v in plots.get("data", plots).items()}
    for name in ("coupled_r2", "learning_curves"):  # both revisions in one plot: the model plots diff
        assert {d["rev"] for d in plots[name][0]["content"]["data"]["values"]} == {"HEAD", "workspace"}, name


def _ignored(path: str) -> bool:
    return subprocess.run(["git", "check-ignore", "-q", "--no-index", path], cwd=REPO).returncode == 0


def test_gitignore_ignores_each_data_directory_not_data_itself() -> None:
    """Every directory a stage writes under data/ is git-ignored by name; data/ itself is not, so git carries
    data/raw.dvc and DVC reads it. With `/data/*` git (and DVC's scmrepo) take data/ for ignored: DVC never reads
    data/raw.dvc, `dvc push` skips the raw logs and `dvc checkout` / `dvc exp run` delete them (dvc#10987)."""
    written = [v for k, v in vars(layout).items() if k.isupper() and isinstance(v, str) and v.startswith("data/")]
    assert layout.RAW in written and len(written) >= 9
    for directory in written:
        assert _ignored(f"{directory}/") and _ignored(f"{directory}/trial01.parquet"), directory
    for path in ("data/", "data/raw.dvc", "data/.gitignore", "data/calibration.dvc"):
        assert not _ignored(path), f"{path} is git-ignored: DVC would not see the .dvc files under data/"


def _files(directory: Path) -> dict[str, bytes]:
    return {p.relative_to(directory).as_posix(): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


def test_dvc_round_trip_keeps_every_raw_log(tmp_path: Path) -> None:
    """The user guide's recipe shared with a colleague: `dvc add data/raw`, repro, `dvc push` to a remote; a fresh
    `git clone`, `dvc pull`, `dvc repro` (nothing to do), `dvc exp run -S`, `dvc checkout`: every raw log arrives
    and stays byte-identical. Needs DVC: about 30 s (two 30-s trials, one coupled and one damping model)."""
    dvc = _dvc_or_skip()
    proj = _project(tmp_path, coupled=("gertler_hagen",), decoupled=("ls",), duration_s=30.0)
    raw = _files(proj / layout.RAW)
    assert sorted(raw) == ["basin_a.mcap", "sea_b.mcap"]
    env = _dvc_env()
    sh = _shell(proj, env)
    sh("git", "init", "-q")
    sh(dvc, "init", "-q")
    sh(dvc, "add", "data/raw")
    sh(dvc, "remote", "add", "-d", "shared", str(tmp_path / "remote"))
    sh("git", "add", ".")
    sh("git", "commit", "-qm", "project")
    sh(dvc, "repro")
    sh("git", "add", "dvc.lock", "reports/headline.json", "reports/plots")
    sh("git", "commit", "-qm", "first run")
    assert sh("git", "status", "--porcelain").strip() == ""
    sh(dvc, "push")

    clone = tmp_path / "clone"
    sh("git", "clone", "-q", str(proj), str(clone))
    cl = _shell(clone, env)
    assert not (clone / layout.RAW).exists()
    cl(dvc, "pull")
    assert _files(clone / layout.RAW) == raw, "dvc pull did not deliver the raw logs"
    assert _ran(cl(dvc, "repro")) == set(), "the pull left outputs out"
    assert _ran(cl(dvc, "exp", "run", "-S", "simulate.band_samples=3")) == {"simulate", "report"}
    assert _files(clone / layout.RAW) == raw, "dvc exp run lost raw logs"
    cl("git", "checkout", "--", ".")  # back to the first run's params and lock: checkout restores its outputs
    cl(dvc, "checkout")
    assert _files(clone / layout.RAW) == raw, "dvc checkout lost raw logs"
    assert (clone / "data/simulation/sea_b/free_run.json").is_file()
    assert _ran(cl(dvc, "repro")) == set()


# ------------------------------------------------------------------------------------- model plots for `dvc plots`

MODEL_PLOTS = {"coupled_r2", "damping_r2", "learning_curves", "free_run_error"}


def _plot_defs() -> dict[str, dict[str, Any]]:
    stages = {full: s for _, full, s in expanded_stages()}
    return {path: props for entry in stages["report"]["plots"] for path, props in entry.items()}


@pytest.fixture
def model_study(request: pytest.FixtureRequest) -> Path:
    """test_report's run with the stages' study files, plus a horizons table of the simulate stage."""
    root: Path = request.getfixturevalue("study_dir")
    (root / "data/simulation/trial02/horizons.json").write_text(json.dumps({
        "gp": {"1.0": {"n_windows": 9, "n_diverged": 0, "mae_end": {"u": 0.01, "r": 0.002}},
               "5.0": {"n_windows": 8, "n_diverged": 0, "mae_end": {"u": 0.03, "r": 0.004}}},
        "ls": {"1.0": {"n_windows": 9, "n_diverged": 0, "mae_end": {"u": 0.02, "r": 0.003}}}}))
    from pipeline.config import load_vehicle
    from stages import report as report_stage

    assert report_stage.run(root, load_vehicle(root / "vehicle.yaml"), load_params(None)).exit_code == 0
    return root


def test_dvc_yaml_defines_the_model_plots_on_fields_the_report_writes(model_study: Path) -> None:
    defs = _plot_defs()
    assert {Path(p).stem for p in defs} >= MODEL_PLOTS | {"valid_fraction", "ingest_rates"}
    for path, props in defs.items():
        rows = json.loads((model_study / path).read_text())
        if Path(path).stem in MODEL_PLOTS:
            assert rows, f"{path}: no rows from the study files"
        for row in rows:
            assert props["x"] in row and props["y"] in row, f"{path}: {props['x']}/{props['y']} not in {row}"
        template = props.get("template")
        if template and template.endswith(".json"):  # a project template: it ships with the code
            assert (REPO / template).is_file(), template
    rows = {Path(p).stem: json.loads((model_study / p).read_text()) for p in defs}
    assert {"model": "wdse_svr · udot_mps2", "final_r2": 0.8, "cv_test_r2": 0.8} in rows["coupled_r2"]
    assert {r["series"] for r in rows["learning_curves"]} == {"u · gp", "u · ls"}
    assert [r["train_samples"] for r in rows["learning_curves"] if r["series"] == "u · ls"] == [40, 220, 400]
    assert {"series": "trial02 · gp · u", "horizon_s": 5.0, "mae": 0.03} in rows["free_run_error"]


def test_model_plot_files_exist_when_their_stage_did_not_run(request: pytest.FixtureRequest) -> None:
    """Every plot in dvc.yaml is an out of the report stage: a run without a study still writes it (empty)."""
    root: Path = request.getfixturevalue("run_dir")
    from pipeline.config import load_vehicle
    from stages import report as report_stage

    report_stage.run(root, load_vehicle(root / "vehicle.yaml"), load_params(None))
    for path in _plot_defs():
        assert (root / path).is_file(), path


def test_dvc_plots_show_gives_the_model_plots(model_study: Path, tmp_path: Path) -> None:
    """`dvc plots show --json` on the report's plot files and this dvc.yaml: a plot per model file, with its rows,
    the series template drawing one line per series. Needs DVC; a few seconds."""
    dvc = shutil.which("dvc") or shutil.which("dvc", path=str(Path(sys.executable).parent))
    if dvc is None:
        pytest.skip("dvc is not installed (pip install -e '.[dvc]'): `dvc plots show` was not run")
    proj = tmp_path / "plots_proj"
    (proj / "reports").mkdir(parents=True)
    shutil.copytree(model_study / "reports/plots", proj / "reports/plots")
    shutil.copy(DVC, proj / "dvc.yaml")
    (proj / "pipeline/report").mkdir(parents=True)
    shutil.copy(REPO / "pipeline/report/dvc_series.json", proj / "pipeline/report/dvc_series.json")
    env = {**os.environ, "DVC_NO_ANALYTICS": "1"}
    subprocess.run([dvc, "init", "--no-scm", "-q"], cwd=proj, env=env, check=True, capture_output=True)
    done = subprocess.run([dvc, "plots", "show", "--json"], cwd=proj, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    shown = json.loads(done.stdout)
    shown = shown.get("data", shown)
    ids = {Path(k).stem: v for k, v in shown.items()}
    assert set(ids) >= MODEL_PLOTS, sorted(ids)
    for name in MODEL_PLOTS:
        spec = ids[name][0]["content"]
        values = spec["data"]["values"]
        assert len(values) == len(json.loads((proj / f"reports/plots/{name}.json").read_text())), name
    for name in ("learning_curves", "free_run_error"):
        spec = ids[name][0]["content"]
        assert spec["encoding"]["color"]["field"] == "series" and spec["mark"]["type"] == "line"
    assert ids["coupled_r2"][0]["content"]["encoding"]["x"]["field"] == "final_r2"


def test_the_dvc_extra_gives_dvc_ruamels_c_parser_with_the_same_values() -> None:
    """DVC parses dvc.yaml, dvc.lock and params.yaml with ``YAML(typ="safe")`` ~14 times a command; ruamel.yaml
    0.19 no longer pulls in its C parser, and without it a `dvc repro` with nothing to do spends ~0.3 s more
    (docs/benchmarks.md, sixth round). The ``[dvc]`` extra installs it; it reads our files (and YAML 1.1/1.2
    corner cases) to the same values as the pure-Python parser."""
    import tomllib

    from ruamel.yaml import YAML
    from ruamel.yaml.main import CParser

    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    for extra in ("dvc", "test"):
        assert any(req.startswith("ruamel.yaml.clib") for req in extras[extra]), extra
    assert CParser is not None and YAML(typ="safe").Parser is CParser
    tricky = "a: on\nb: yes\nc: 0777\nd: 1_000\ne: 12:30\nf: 1e3\ng: .5\nh: ~\ni: NO\nj: 0o17\nk: 2001-12-14\n"
    for text in (DVC.read_text(), (REPO / "params.yaml").read_text(), tricky):
        assert YAML(typ="safe").load(text) == YAML(typ="safe", pure=True).load(text)
