"""The property-based config campaign (issue 36, item 3): every generated params or vehicle config is either
refused at load with a ConfigError naming the file and the key, or loads; never another exception (a traceback
from inside a library), never a load that takes seconds. Bounded: a fixed number of examples, derandomized
(a fixed seed), so the suite is reproducible; ``bench/fuzz_configs.py`` runs thousands."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

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
