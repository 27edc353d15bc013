"""``auvid demo`` writes its configs as ``auvid init`` does: the schema line first, naming a copy of the schema
beside the config (valid wherever the run directory moves), the YAML unchanged."""

from __future__ import annotations

import shutil
from pathlib import Path

import yaml

from pipeline import demo
from pipeline.config import load_params, load_vehicle
from pipeline.config.schemas import MODELINE, schema_modeline, schema_path


def schema_named_by(config: Path) -> Path:
    """The file a config's first line names, resolved as the YAML language server does: relative to the config."""
    first = config.read_text(encoding="utf-8").splitlines()[0]
    assert first.startswith(MODELINE), first
    return config.parent / first.removeprefix(MODELINE)


def test_demo_configs_name_their_schema(tmp_path: Path) -> None:
    setup = demo.prepare(tmp_path / "run", duration_s=4.0)
    for path, kind in ((setup.vehicle_path, "vehicle"), (setup.params_path, "params")):
        lines = path.read_text(encoding="utf-8").splitlines()
        assert lines[0] == schema_modeline(kind, beside=True) == f"{MODELINE}./{kind}.schema.json", path
        assert schema_named_by(path).read_bytes() == schema_path(kind).read_bytes()
        assert sum(line.startswith(demo.MODELINE_PREFIX) for line in lines) == 1
        assert isinstance(yaml.safe_load(path.read_text()), dict)
    load_vehicle(setup.vehicle_path)  # still valid configs
    assert load_params(setup.params_path).features.test_trials == [setup.trials[-1]]
    again = demo.prepare(tmp_path / "run", duration_s=4.0)  # a second demo in the same place: still one line
    assert again.vehicle_path.read_text().count(demo.MODELINE_PREFIX) == 1


def test_demo_schema_lines_stay_valid_when_the_run_directory_moves(tmp_path: Path) -> None:
    """Moved (and the old place gone), the configs still name an existing schema, the package's own."""
    setup = demo.prepare(tmp_path / "run", duration_s=4.0)
    moved = shutil.move(tmp_path / "run", tmp_path / "elsewhere" / "basin")
    for name, kind in (("vehicle.yaml", "vehicle"), ("params.yaml", "params")):
        config = Path(moved) / name
        assert not (setup.root / name).exists()
        assert schema_named_by(config).resolve().is_relative_to(Path(moved).resolve()), name  # goes with it
        assert schema_named_by(config).read_bytes() == schema_path(kind).read_bytes(), name
