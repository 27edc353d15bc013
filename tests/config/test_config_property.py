"""The property-based config campaign (issue 36, item 3): every generated params or vehicle config is either
refused at load with a ConfigError naming the file and the key, or loads; never another exception (a traceback
from inside a library), never a load that takes seconds. Bounded: a fixed number of examples, derandomized
(a fixed seed), so the suite is reproducible; ``bench/fuzz_configs.py`` runs thousands."""

from __future__ import annotations

import copy
import tempfile
import warnings
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings

from pipeline.config import load_params
from pipeline.errors import ConfigError
from tests.config.strategies import PARAMS, VEHICLE, edited, outcome, write

CAMPAIGN = settings(max_examples=300, derandomize=True, database=None, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _check(kind: str, case: tuple[dict[str, Any], list[str]]) -> None:
    doc, what = case
    with tempfile.TemporaryDirectory() as tmp:
        path = write(Path(tmp) / f"{kind}.yaml", doc)
        result, detail = outcome(kind, path, time_limit_s=5.0)
    assert result in ("loaded", "refused"), f"{kind} with {what}: {result}: {detail}"


@CAMPAIGN
@given(edited(PARAMS))
def test_every_generated_params_config_loads_or_is_refused_naming_file_and_key(
        case: tuple[dict[str, Any], list[str]]) -> None:
    _check("params", case)


@CAMPAIGN
@given(edited(VEHICLE))
def test_every_generated_vehicle_config_loads_or_is_refused_naming_file_and_key(
        case: tuple[dict[str, Any], list[str]]) -> None:
    _check("vehicle", case)


def test_the_campaign_bases_load() -> None:
    """The unedited configs load: a refusal in the campaign is the edit's doing."""
    with tempfile.TemporaryDirectory() as tmp:
        assert outcome("params", write(Path(tmp) / "params.yaml", PARAMS)) == ("loaded", "")
        assert outcome("vehicle", write(Path(tmp) / "vehicle.yaml", VEHICLE)) == ("loaded", "")


@pytest.mark.parametrize(("key", "value"), [("inertia", 1.7976931348623157e308), ("inertia", -1.7976931348623157e308),
                                            ("added_mass", 1.7976931348623157e308)])
def test_a_matrix_at_the_float_maximum_is_refused_without_a_numpy_warning(tmp_path: Path, key: str,
                                                                         value: float) -> None:
    """Found by the campaign: (M + Mᵀ) / 2 overflowed, and numpy printed 'overflow encountered in add' from
    library code before the refusal."""
    doc = copy.deepcopy(VEHICLE)
    matrix = doc["rigid_body"]["inertia_kgm2"] if key == "inertia" else doc["added_mass"]
    matrix[0][0] = matrix[0][1] = matrix[1][0] = value
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert outcome("vehicle", write(tmp_path / "vehicle.yaml", doc)) == (
            "refused", "rigid_body.inertia_kgm2" if key == "inertia" else "added_mass")


@pytest.mark.parametrize(("section", "key", "value", "says"), [
    ("sync", "rate_hz", 1e-300, "greater than or equal to 0.001"),  # a period beyond int64 nanoseconds
    ("coupled", "n_jobs", 1_500_000_000, "1 to 1024"),
    ("coupled", "n_jobs", 2**70, "1 to 1024"),
    ("coupled", "max_evals", 2**63, "less than or equal to 10000"),
    ("coupled", "max_samples", 2**64, "less than or equal to 1000000"),
    ("coupled", "tuning_folds", 3_700_000_000, "less than or equal to 100"),
    ("decoupled", "max_samples", 2**64, "less than or equal to 10000000"),
    ("decoupled", "gp_max_samples", 10**9, "less than or equal to 20000"),
    ("differentiate", "savgol_window_s", 2.0**63, "up to 3600"),
    ("differentiate", "sigma_s", 1e58, "up to 3600"),
])
def test_params_the_campaign_found_unbounded_are_refused(tmp_path: Path, section: str, key: str, value: Any,
                                                         says: str) -> None:
    """Found loading by bench/fuzz_configs.py (seed 3601): counts and widths beyond memory, time or int64."""
    doc = copy.deepcopy(PARAMS)
    doc[section][key] = value
    path = write(tmp_path / "params.yaml", doc)
    with pytest.raises(ConfigError) as info:
        load_params(path)
    assert info.value.file == str(path) and info.value.field == f"{section}.{key}" and says in str(info.value)


def test_a_csv_skip_rows_beyond_the_line_budget_is_refused(tmp_path: Path) -> None:
    doc = copy.deepcopy(VEHICLE)
    doc["streams"]["tank"]["csv"]["skip_rows"] = 2**64  # pandas: OverflowError at ingest
    assert outcome("vehicle", write(tmp_path / "vehicle.yaml", doc)) == ("refused", "streams.tank.csv.skip_rows")


@pytest.mark.parametrize("outputs", [["udot_mps2", "rdot_radps2"], ["vdot_mps2", "udot_mps2", "rdot_radps2"]])
def test_explicit_models_with_other_outputs_than_udot_vdot_rdot_are_refused(tmp_path: Path,
                                                                             outputs: list[str]) -> None:
    """Found by the run campaign (``bench/fuzz_configs.py --run``, seed 3711): ``drop coupled.outputs.1`` loaded,
    and the tune stage ended in a traceback from inside the McFarland-Whitcomb estimator (two columns, not three);
    the same outputs reordered would fit each of its equations to another equation's target without a word."""
    doc = copy.deepcopy(PARAMS)
    doc["coupled"]["outputs"] = outputs
    path = write(tmp_path / "params.yaml", doc)
    with pytest.raises(ConfigError) as info:
        load_params(path)
    assert info.value.file == str(path) and info.value.field == "coupled.outputs"
    assert "['gertler_hagen', 'mcfarland_whitcomb', 'fossen', 'graybox_fossen']" in str(info.value)
    doc["coupled"]["models"] = ["rbf_svr", "wdse_svr"]  # the SVRs predict each output on its own: any set loads
    load_params(write(tmp_path / "params.yaml", doc))
