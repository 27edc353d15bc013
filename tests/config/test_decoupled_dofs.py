"""The decoupled study takes the DOFs the vehicle measures (issue 34, item 3): ``decoupled.dofs`` left at its
default (u v r) becomes the default's measured DOFs, or w on a heave-only ROV, with a log line; DOFs the user names
that the sensors do not measure are refused naming the key; an ordinary vehicle's params are left as they are (the
same object, so the same bytes out). Then the whole way on the depth-hold trial of
``tests/estimation/test_heave_only.py``: with the params' defaults the decoupled stage fits heave alone."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest
import yaml

from pipeline.config import Params, config_hash, measured_dofs, parse
from pipeline.errors import ConfigError
from pipeline.sim import load_example_vehicle
from stages import decoupled as decoupled_stage
from stages import derive as derive_stage
from stages import differentiate as differentiate_stage
from stages import features as features_stage
from stages import ingest as ingest_stage
from stages import sync as sync_stage
from stages.common import load_configs
from tests.config.test_coupled_skip import HEAVE, HEAVE_AND_YAW_RATE, PLANAR, _vehicle
from tests.estimation.test_heave_only import VEHICLE, ZW, ZWW, write_trial

PLANAR_AND_YAW_RATE = ({**PLANAR[0], "rates": {"r": "r_radps"}}, [*PLANAR[1], "r_radps"])


@pytest.mark.parametrize(("sensors", "dofs"), [
    (HEAVE, ["w"]),                    # depth alone: its w, not u v r's columns of zeros
    (HEAVE_AND_YAW_RATE, ["w"]),       # a yaw rate beside the depth: still a heave vehicle
    (PLANAR, ["u", "v"]),              # no yaw rate: r is 0 in the store
    (PLANAR_AND_YAW_RATE, ["u", "v", "r"]),
])
def test_the_default_takes_the_dofs_the_vehicle_measures(sensors, dofs, caplog: pytest.LogCaptureFixture) -> None:
    vehicle, params = _vehicle(*sensors), Params()
    with caplog.at_level(logging.INFO, logger="pipeline.config"):
        resolved = measured_dofs(vehicle, params)
    assert resolved.decoupled.dofs == dofs
    assert resolved.model_dump(exclude={"decoupled"}) == params.model_dump(exclude={"decoupled"})
    if dofs == ["u", "v", "r"]:
        assert resolved is params and not caplog.records
    else:
        assert "decoupled.dofs left at its default (u, v, r): the vehicle 'rov' measures " in caplog.text
        assert caplog.text.rstrip().endswith(f"so the decoupled study takes {', '.join(dofs)}")
        assert measured_dofs(vehicle, resolved) is resolved  # resolved once: a second call changes nothing


def test_an_ordinary_vehicle_keeps_its_params_and_their_hash() -> None:
    vehicle = load_example_vehicle()
    for params in (Params(), parse(Params, {"decoupled": {"dofs": ["u", "v", "w", "r"], "models": ["ls"]}})):
        assert measured_dofs(vehicle, params) is params
    assert config_hash(measured_dofs(vehicle, Params())) == config_hash(Params())


@pytest.mark.parametrize(("dofs", "key", "named"), [(["u", "w"], "decoupled.dofs.0", "u"),
                                                    (["w", "r"], "decoupled.dofs.1", "r")])
def test_dofs_the_user_names_but_the_vehicle_does_not_measure_are_refused(dofs, key, named) -> None:
    params = parse(Params, {"decoupled": {"dofs": dofs}})
    with pytest.raises(ConfigError, match=f"decoupled.dofs names {named}, which the vehicle 'rov' does not measure "
                                          r"\(its sensors measure w only\)") as err:
        measured_dofs(_vehicle(*HEAVE), params, "params.yaml")
    assert err.value.field == key and "params.yaml" in str(err.value)
    explicit = parse(Params, {"decoupled": {"dofs": ["w"]}})
    assert measured_dofs(_vehicle(*HEAVE), explicit) is explicit


def test_a_heave_only_vehicle_with_the_default_params_fits_heave_alone(tmp_path: Path) -> None:
    """params.yaml says nothing of decoupled.dofs: the stages, given the configs as ``auvid`` loads them, fit w's
    damping (the truth's Z_w, Z_ww) and no u / v / r model."""
    (tmp_path / "heaver.yaml").write_text(yaml.safe_dump(VEHICLE, sort_keys=False))
    (tmp_path / "params.yaml").write_text(yaml.safe_dump({"decoupled": {"models": ["ls"], "n_jobs": 1}}))
    write_trial(tmp_path / "dives" / "hold01")
    vehicle, params = load_configs(tmp_path, tmp_path / "heaver.yaml", None)
    assert params.decoupled.dofs == ["w"]
    for stage, extra in ((ingest_stage, {"logs": [tmp_path / "dives" / "hold01"]}), (sync_stage, {}),
                         (differentiate_stage, {}), (derive_stage, {}), (features_stage, {}), (decoupled_stage, {})):
        result = stage.run(tmp_path, vehicle, params, **extra)
        assert not result.quarantined, (stage.NAME, result.quarantined)
    models = sorted(p.name for p in decoupled_stage.models_dir(tmp_path).glob("*.joblib"))
    assert models == ["w_ls.joblib"]
    learned = json.loads((decoupled_stage.evaluation_dir(tmp_path) / "metrics.json").read_text())["results"]
    assert set(learned) == {"w"}
    assert learned["w"]["ls"]["learned"]["d_l"] == pytest.approx(ZW, rel=0.02)
    assert learned["w"]["ls"]["learned"]["d_q"] == pytest.approx(ZWW, rel=0.02)
