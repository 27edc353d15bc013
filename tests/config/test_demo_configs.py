"""``auvid demo`` writes its configs as ``auvid init`` does: the schema line first, the YAML unchanged."""

from __future__ import annotations

from pathlib import Path

import yaml

from pipeline import demo
from pipeline.config import load_params, load_vehicle
from pipeline.config.schemas import schema_modeline, schema_path


def test_demo_configs_name_their_schema(tmp_path: Path) -> None:
    setup = demo.prepare(tmp_path / "run", duration_s=4.0)
    for path, kind in ((setup.vehicle_path, "vehicle"), (setup.params_path, "params")):
        lines = path.read_text(encoding="utf-8").splitlines()
        assert lines[0] == schema_modeline(kind), path
        assert Path(lines[0].split("$schema=", 1)[1]) == schema_path(kind) and schema_path(kind).is_file()
        assert sum(line.startswith(demo.MODELINE_PREFIX) for line in lines) == 1
        assert isinstance(yaml.safe_load(path.read_text()), dict)
    load_vehicle(setup.vehicle_path)  # still valid configs
    assert load_params(setup.params_path).features.test_trials == [setup.trials[-1]]
    again = demo.prepare(tmp_path / "run", duration_s=4.0)  # a second demo in the same place: still one line
    assert again.vehicle_path.read_text().count(demo.MODELINE_PREFIX) == 1
