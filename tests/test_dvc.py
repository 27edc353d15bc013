"""dvc.yaml, checked structurally without DVC installed (a real `dvc repro` check: bench/dvc_repro.sh)."""

from __future__ import annotations

import importlib.util
import re
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml

from pipeline.config import Params, load_params
from pipeline.models.card import card_path
from stages.common import STAGE_ORDER

REPO = Path(__file__).resolve().parents[1]
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


def test_every_stage_of_the_dag_is_there_in_order() -> None:
    names = list(dict.fromkeys(name for name, _, _ in expanded_stages()))
    assert [n for n in names if n in STAGE_ORDER] == list(STAGE_ORDER)


def test_each_stage_runs_its_own_existing_module() -> None:
    for name, full, stage in expanded_stages():
        match = re.match(r"python -m stages\.(\w+)\b", stage["cmd"])
        assert match, f"{full}: cmd must be `python -m stages.<name> ...`: {stage['cmd']!r}"
        assert match.group(1) == name, f"{full}: runs stages.{match.group(1)}, not its own module"
        assert importlib.util.find_spec(f"stages.{name}") is not None, f"{full}: no module stages/{name}.py"
        assert f"stages/{name}.py" in _entries(stage.get("deps")), f"{full}: its own script is not a dep"


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
    assert _entries(stages["report"]["metrics"]) == ["reports/metrics.json"]
    assert len(_entries(stages["report"]["plots"])) >= 1
    ignore = (REPO / ".dvcignore").read_text().split()
    assert "__pycache__" in ignore


@pytest.mark.parametrize("trial", ["trial01", "trial02", "trial03"])
def test_foreach_trials_match_the_example(trial: str) -> None:
    params = load_params(REPO / "params.yaml")
    names = {full for _, full, _ in expanded_stages()}
    for stage in ("sync", "differentiate", "derive"):
        assert f"{stage}@{trial}" in names
    assert params.features.test_trials == ["trial03"]


def test_train_outs_cover_every_coupled_model() -> None:
    from stages.tune import hyperparameters_path

    params = load_params(REPO / "params.yaml")
    stages = {full: s for _, full, s in expanded_stages()}
    outs = set(_entries(stages["train"]["outs"]))
    for model in params.coupled.models:
        joblib_path = Path("data/models/coupled") / f"{model}.joblib"
        assert joblib_path.as_posix() in outs and card_path(joblib_path).as_posix() in outs
    tune_outs = set(_entries(stages["tune"]["outs"]))
    assert hyperparameters_path(Path(".")).as_posix() in tune_outs
