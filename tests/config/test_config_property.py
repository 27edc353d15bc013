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
