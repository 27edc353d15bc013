"""Generated configs name their JSON Schema for editors; the schemas ship inside the package."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from pipeline.cli.init import starter_config
from pipeline.config.schemas import schema_modeline, schema_path
from pipeline.sim import generate_trial, load_example_vehicle, write_trial

REPO = Path(__file__).resolve().parents[2]


def test_schema_files_are_the_repository_s() -> None:
    for kind in ("vehicle", "params"):
        path = schema_path(kind)
        assert path.is_file(), path
        assert path.read_bytes() == (REPO / "schemas" / f"{kind}.schema.json").read_bytes()
        doc = json.loads(path.read_text())
        assert doc["type"] == "object" and doc["properties"]


def test_auvid_init_writes_the_modeline_first(tmp_path: Path) -> None:
    log = tmp_path / "run01.mcap"
    write_trial(generate_trial(load_example_vehicle(), 3.0, seed=1), "mcap", log)
    text = starter_config([log]).text
    first = text.splitlines()[0]
    assert first == schema_modeline("vehicle")
    assert first.startswith("# yaml-language-server: $schema=")
    assert Path(first.split("$schema=", 1)[1]) == schema_path("vehicle")
    assert yaml.safe_load(text)["name"] == "run01"  # a comment: the YAML is unchanged


def test_auvid_init_puts_the_schema_beside_the_config_moved_or_not(tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """`auvid init -o DIR/dagon.yaml` names ./vehicle.schema.json, written into DIR: the line stays valid when DIR
    moves; to stdout the line names the package's schema (there is no directory to put a copy in)."""
    from pipeline import cli
    from pipeline.config.schemas import MODELINE

    log = tmp_path / "run01.mcap"
    write_trial(generate_trial(load_example_vehicle(), 3.0, seed=1), "mcap", log)
    config = tmp_path / "vehicle" / "dagon.yaml"
    config.parent.mkdir()
    assert cli.main(["init", str(log), "-o", str(config)]) == 0
    moved = Path(shutil.move(config.parent, tmp_path / "lab" / "dagon")) / "dagon.yaml"
    first = moved.read_text().splitlines()[0]
    assert first == f"{MODELINE}./vehicle.schema.json"
    assert (moved.parent / "vehicle.schema.json").read_bytes() == schema_path("vehicle").read_bytes()
    capsys.readouterr()
    assert cli.main(["init", str(log), "-o", "-"]) == 0
    assert capsys.readouterr().out.splitlines()[0] == schema_modeline("vehicle")


def test_the_schemas_are_package_data(tmp_path: Path) -> None:
    """What setuptools puts in the wheel (build_py): pipeline/schemas/*.json, copied as files."""
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, src / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in ("pipeline", "stages", "schemas"):
        shutil.copytree(REPO / name, src / name, symlinks=True, ignore=ignore)
    done = subprocess.run([sys.executable, "-c", "from setuptools import setup; setup()", "-q", "build_py"],
                          cwd=src, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    built = src / "build/lib/pipeline/schemas"
    assert sorted(p.name for p in built.iterdir()) == sorted(p.name for p in (REPO / "schemas").glob("*.json"))
    assert not built.is_symlink() and all(p.is_file() and not p.is_symlink() for p in built.iterdir())
