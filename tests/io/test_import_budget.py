"""Which heavy modules the fast paths load (issue 15, "Imports on a budget").

Each case runs in a fresh interpreter and inspects ``sys.modules`` at the end: a module that is not there cost
nothing, however loaded the machine is. The timings themselves are in docs/benchmarks.md (``bench/ingest.py``);
this test only keeps a heavy import from creeping back into ``auvid --help``, ``import pipeline.io`` or a whole
``auvid ingest`` run. Where a module is found, the failure names the import chain to look at:
``python -X importtime -c "<the case's code>"`` shows who imported it.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from tests.io import helpers as io

ROOT = Path(__file__).resolve().parents[2]

#: Never on the ingest path: the modelling stack and optional extras.
MODELLING = ("pandas", "scipy", "sklearn", "matplotlib", "dask", "distributed", "tqdm")
#: Not needed to print help or read a log's bytes either.
CONFIG_AND_TABLES = ("joblib", "pydantic", "pyarrow", "yaml", "numpy", "mcap", "rosbags", "zstandard", "lz4",
                     "adbc_driver_manager", "adbc_driver_sqlite")
#: What the sqlite3 storage used to fetch through: ADBC imports pyarrow.dataset, and that imports pandas.
ADBC = ("adbc_driver_manager", "adbc_driver_sqlite", "pyarrow.dataset")
#: rosbags' standard ROS 2 types (~0.1 s of CPU): needed only for a type that the log does not define.
STANDARD_TYPES = ("rosbags.typesys.stores.ros2_jazzy",)
#: joblib (~0.08 s of CPU): imported where a pool starts; one log per run starts none.
POOL = ("joblib",)
#: numpy's masked arrays (~10 ms): numpy 2 imports them at the first np.unique; no reader needs them.
MASKED = ("numpy.ma",)

PROBE = """
import json, sys
{code}
print("\\nLOADED=" + json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in {tops!r} or m in {names!r})))
"""


def loaded(code: str, names: tuple[str, ...], cwd: Path) -> list[str]:
    """The modules of ``names`` (or below them) that a fresh interpreter holds after running ``code``."""
    tops = sorted({n.split(".")[0] for n in names})
    script = PROBE.format(code=code, tops=tops, names=list(names))
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=cwd, timeout=120,
                          stdin=subprocess.DEVNULL, check=False)
    marker = [ln for ln in proc.stdout.splitlines() if ln.startswith("LOADED=")]
    assert marker, f"probe failed (exit {proc.returncode}):\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    found = json.loads(marker[-1][len("LOADED="):])
    return sorted(n for n in names if n in found)


def test_auvid_help_loads_nothing_heavy(tmp_path: Path) -> None:
    code = ("from pipeline.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit as e:\n    assert e.code == 0, e.code")
    assert loaded(code, MODELLING + CONFIG_AND_TABLES, tmp_path) == []


@pytest.mark.parametrize("command", ["ingest", "run", "inspect", "init", "models", "export"])
def test_subcommand_help_loads_nothing_heavy(tmp_path: Path, command: str) -> None:
    code = ("from pipeline.cli import main\n"
            f"try:\n    main([{command!r}, '--help'])\nexcept SystemExit as e:\n    assert e.code == 0, e.code")
    assert loaded(code, MODELLING + CONFIG_AND_TABLES, tmp_path) == []


def test_import_pipeline_io_loads_no_modelling_or_config_stack(tmp_path: Path) -> None:
    heavy = MODELLING + ("joblib", "pydantic", "pyarrow") + ADBC
    assert loaded("import pipeline.io", heavy, tmp_path) == []


def test_loading_a_vehicle_config_loads_no_tables_or_modelling_stack(tmp_path: Path) -> None:
    """The config's own checks (the mass matrix, pipeline.config.rigid_body) need numpy, not pandas or pyarrow."""
    vehicle = tmp_path / "vehicle.yaml"
    vehicle.write_text(yaml.safe_dump(VEHICLE), encoding="utf-8")
    code = f"from pipeline.config import load_vehicle\nload_vehicle({str(vehicle)!r})"
    assert loaded(code, MODELLING + ("pyarrow", "joblib"), tmp_path) == []


# -- a whole `auvid ingest` on a tiny log of each format ------------------------------------------------------
VEHICLE = {
    "name": "budgetbot",
    "rigid_body": {"mass_kg": 10, "inertia_kgm2": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
    "added_mass": [[0.0] * 6 for _ in range(6)],
    "thrusters": [{"name": "th1", "speed_signal": "n1_rpm", "position_m": [0, 0, 0], "direction": [1, 0, 0],
                   "thrust": {"k_fwd_N_per_rpm2": 1e-5}}],
    "sensors": {"dvl": {"velocity": ["u_mps", "v_mps", "w_mps"]},
                "attitude": {"quaternion": "att_quat", "convention": "flu_enu"}},
    "streams": {
        "dvl": {"topic": "/dvl/data", "clock": "header",
                "signals": {"u_mps": {"field": "velocity.x"}, "v_mps": {"field": "velocity.y"},
                            "w_mps": {"field": "velocity.z"}}},
        "imu": {"topic": "/ahrs/imu", "clock": "header", "signals": {"att_quat": {"field": "orientation"}}},
        "thrusters": {"topic": "/thrusters/joint_states", "clock": "log",
                      "signals": {"n1_rpm": {"field": "velocity[name=th1]", "unit": "rad/s"}}},
    },
}

WRITERS: dict[str, Any] = {
    "mcap": lambda d, m: io.write_mcap(d / "trial01.mcap", m),
    "mcap-uncompressed": lambda d, m: io.write_mcap(d / "trial01.mcap", m, compression="none"),
    "ros2-mcap": lambda d, m: io.write_rosbag2(d / "trial01", m, storage="mcap"),
    "ros2-sqlite3": lambda d, m: io.write_rosbag2(d / "trial01", m, storage="sqlite3"),
    "ros1": lambda d, m: io.write_rosbag1(d / "trial01.bag", m),
}


@pytest.mark.parametrize("write", list(WRITERS.values()), ids=list(WRITERS))
def test_auvid_ingest_loads_no_modelling_stack(tmp_path: Path, write: Callable[[Path, list[io.Msg]], Path]) -> None:
    raw = tmp_path / "raw"
    raw.mkdir()
    log = write(raw, io.trial(n=12))
    vehicle = tmp_path / "vehicle.yaml"
    vehicle.write_text(yaml.safe_dump(VEHICLE), encoding="utf-8")
    run = tmp_path / "run"
    code = ("from pipeline.cli import main\n"
            f"code = main(['ingest', '-q', '--root', {str(run)!r}, '--vehicle', {str(vehicle)!r}, {str(log)!r}])\n"
            "assert code == 0, code")
    found = loaded(code, MODELLING + ADBC + STANDARD_TYPES + POOL + MASKED, tmp_path)
    assert (run / "data" / "signals" / "trial01" / "dvl.parquet").exists()
    assert found == [], f"auvid ingest of {log.name} loaded {found}"


def test_auvid_ingest_with_configs_validated_before_loads_no_pydantic(tmp_path: Path) -> None:
    """The first run validates the configs (pydantic, ~0.2 s of CPU) and keeps a snapshot; the next reads that
    (pipeline.config.snapshot) and needs neither pydantic nor, for an MCAP file, a YAML parser."""
    log = io.write_mcap(tmp_path / "trial01.mcap", io.trial(n=12))
    vehicle = tmp_path / "vehicle.yaml"
    vehicle.write_text(yaml.safe_dump(VEHICLE), encoding="utf-8")
    code = ("from pipeline.cli import main\n"
            f"code = main(['ingest', '-q', '--root', {str(tmp_path / 'run')!r}, '--vehicle', {str(vehicle)!r}, "
            f"{str(log)!r}])\nassert code == 0, code")
    assert loaded(code, ("pydantic", "yaml"), tmp_path) == ["pydantic", "yaml"]
    # Nor the standard library's sqlite3: a bag of sqlite3 storage imports it.
    assert loaded(code, ("pydantic", "yaml", "sqlite3") + MODELLING + POOL, tmp_path) == []


def test_auvid_inspect_starts_no_pool_machinery(tmp_path: Path) -> None:
    """inspect, init, models and export fan out no joblib work: the CLI enters no parallel backend for them; and
    pandas parses text logs only, so inspecting a binary one does not import it."""
    log = io.write_mcap(tmp_path / "trial01.mcap", io.trial(n=12))
    code = ("import contextlib, io\nfrom pipeline.cli import main\n"
            f"with contextlib.redirect_stdout(io.StringIO()):\n    assert main(['inspect', {str(log)!r}]) == 0")
    assert loaded(code, MODELLING + ("joblib",), tmp_path) == []


# -- the per-stage path: each stage imports what its configured method needs (issue 35) ------------------------
#: The grid filters' modules: scipy.signal (Savitzky-Golay, ~0.6 CPU-s to import) and scipy.ndimage (Gaussian).
GRID_FILTERS = ("scipy.signal", "scipy.ndimage")


@pytest.mark.parametrize(("method", "expected"), [("kalman", []), ("gaussian", ["scipy.ndimage"]),
                                                  ("savgol", ["scipy.ndimage", "scipy.signal"])])
def test_differentiate_imports_only_its_methods_filters(tmp_path: Path, method: str, expected: list[str]) -> None:
    """``python -m stages.differentiate`` as DVC runs it, up to its method's function (and, for savgol, one filter
    call): the default smoother never imports the grid filters' scipy.signal or scipy.ndimage."""
    code = ("import numpy as np\nimport stages.differentiate\n"
            "from pipeline.estimation.differentiate import method_function\n"
            f"method_function({method!r})\n")
    if method == "savgol":
        code += ("from pipeline.estimation.savgol import savgol_filters\n"
                 "savgol_filters(np.sin(np.arange(50.0)), 7, 2, 0.1)\n")
    assert loaded(code, GRID_FILTERS, tmp_path) == expected
