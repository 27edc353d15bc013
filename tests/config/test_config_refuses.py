"""A config that refuses nonsense (issue 17, item 4): the malformed vehicle files of the fuzzing campaign, and
malformed params, each refused with a ConfigError that names the file and the offending key.

Each vehicle case starts from the example vehicle ``pipeline/sim/dagon.yaml`` and changes one thing.
"""

from __future__ import annotations

import copy
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from pipeline.config import load_params, load_vehicle
from pipeline.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]
DAGON = ROOT / "pipeline" / "sim" / "dagon.yaml"
TEXT = DAGON.read_text(encoding="utf-8")
BASE: dict[str, Any] = yaml.safe_load(TEXT)

Edit = Callable[[dict[str, Any]], None]


def _walk(doc: Any, dotted: str) -> tuple[Any, Any]:
    *parents, last = dotted.split(".")
    for part in parents:
        doc = doc[int(part)] if isinstance(doc, list) else doc[part]
    return doc, int(last) if isinstance(doc, list) else last


def put(dotted: str, value: Any) -> Edit:
    def edit(doc: dict[str, Any]) -> None:
        parent, key = _walk(doc, dotted)
        parent[key] = value
    return edit


def drop(dotted: str) -> Edit:
    def edit(doc: dict[str, Any]) -> None:
        parent, key = _walk(doc, dotted)
        del parent[key]
    return edit


def rename_stream(old: str, new: str) -> Edit:
    def edit(doc: dict[str, Any]) -> None:
        doc["streams"] = {(new if k == old else k): v for k, v in doc["streams"].items()}
    return edit


def move_signal(signal: str, source: str, target: str) -> Edit:
    """Define ``signal`` in ``target`` as well (a signal in two streams)."""
    def edit(doc: dict[str, Any]) -> None:
        doc["streams"][target]["signals"][signal] = doc["streams"][source]["signals"][signal]
    return edit


def add_csv_stream(**csv: Any) -> Edit:
    """A CSV stream ``tank`` with these ``csv`` options."""
    def edit(doc: dict[str, Any]) -> None:
        doc["streams"]["tank"] = {"file": "tank.csv", "clock": "column", "optional": True,
                                  "csv": {"time_column": "t", **csv}, "signals": {"x_tank_m": {"field": "x"}}}
    return edit


INF, NAN = float("inf"), float("nan")
I3 = [[5.0, 0.0, 0.0], [0.0, 15.06, 0.0], [0.0, 0.0, 18.06]]


def with_row(matrix: list[list[float]], i: int, row: list[float]) -> list[list[float]]:
    out = copy.deepcopy(matrix)
    out[i] = row
    return out


MA = BASE["added_mass"]

VEHICLE_CASES = [
    # rigid body: finite positive mass, never a boolean; its weight must be a finite number of newtons
    pytest.param(put("rigid_body.mass_kg", INF), "rigid_body.mass_kg", "finite", id="mass-inf"),
    pytest.param(put("rigid_body.mass_kg", NAN), "rigid_body.mass_kg", "finite", id="mass-nan"),
    pytest.param(put("rigid_body.mass_kg", 1e308), "rigid_body.mass_kg", "weight", id="mass-1e308"),
    # (M = M_RB + M_A cannot overflow within the bounds on mass and centres below: refused at the centre)
    pytest.param(put("rigid_body", {**BASE["rigid_body"], "mass_kg": 1e300, "cg_m": [0.0, 0.0, 1e10]}), "rigid_body",
                 "from the reference point", id="mass-1e300-far-cg"),
    pytest.param(put("rigid_body.mass_kg", True), "rigid_body.mass_kg", "boolean", id="mass-true"),
    pytest.param(put("rigid_body.mass_kg", 0.0), "rigid_body.mass_kg", "greater than 0", id="mass-zero"),
    pytest.param(put("rigid_body.mass_kg", -75.0), "rigid_body.mass_kg", "greater than 0", id="mass-negative"),
    pytest.param(put("rigid_body.mass_kg", "heavy"), "rigid_body.mass_kg", "number", id="mass-string"),
    pytest.param(drop("rigid_body.mass_kg"), "rigid_body.mass_kg", "Field required", id="mass-missing"),
    # inertia: 3x3, finite, symmetric, positive definite
    pytest.param(put("rigid_body.inertia_kgm2", I3[:2]), "rigid_body.inertia_kgm2", "3x3", id="inertia-two-rows"),
    pytest.param(put("rigid_body.inertia_kgm2", with_row(I3, 1, [0.0, 15.06])), "rigid_body.inertia_kgm2", "3x3",
                 id="inertia-short-row"),
    pytest.param(put("rigid_body.inertia_kgm2", with_row(I3, 0, [-5.0, 0.0, 0.0])), "rigid_body.inertia_kgm2",
                 "positive definite", id="inertia-negative-diagonal"),
    pytest.param(put("rigid_body.inertia_kgm2", with_row(I3, 0, [0.0, 0.0, 0.0])), "rigid_body.inertia_kgm2",
                 "positive definite", id="inertia-zero-diagonal"),
    pytest.param(put("rigid_body.inertia_kgm2", with_row(I3, 2, [0.0, 0.0, NAN])), "rigid_body.inertia_kgm2",
                 "finite", id="inertia-nan"),
    pytest.param(put("rigid_body.inertia_kgm2", with_row(I3, 0, [5.0, 1.0, 0.0])), "rigid_body.inertia_kgm2",
                 "symmetric", id="inertia-asymmetric"),
    pytest.param(put("rigid_body.inertia_kgm2", [[5.0, 9.0, 0.0], [9.0, 15.06, 0.0], [0.0, 0.0, 18.06]]),
                 "rigid_body.inertia_kgm2", "positive definite", id="inertia-indefinite"),
    pytest.param(put("rigid_body.inertia_kgm2", 5.0), "rigid_body.inertia_kgm2", "list", id="inertia-scalar"),
    # gravity, buoyancy, centres
    pytest.param(put("rigid_body.gravity_mps2", 0.0), "rigid_body.gravity_mps2", "greater than or equal to 0.1",
                 id="gravity-0"),
    pytest.param(put("rigid_body.gravity_mps2", -9.81), "rigid_body.gravity_mps2", "greater than or equal to 0.1",
                 id="gravity-negative"),
    pytest.param(put("rigid_body.gravity_mps2", INF), "rigid_body.gravity_mps2", "finite", id="gravity-inf"),
    pytest.param(put("rigid_body.buoyancy_N", -740.0), "rigid_body.buoyancy_N", "greater than or equal",
                 id="buoyancy-negative"),
    pytest.param(put("rigid_body.cg_m", [0.0, NAN, 0.05]), "rigid_body.cg_m", "finite", id="cg-nan"),
    pytest.param(put("rigid_body.cg_m", [0.0, 0.05]), "rigid_body.cg_m", "", id="cg-two-entries"),
    # added mass: 6x6, finite, symmetric, positive semi-definite; M = M_RB + M_A positive definite, conditioned
    pytest.param(put("added_mass", with_row(MA, 3, [0.0, 0.0, 0.0, 2.0, 0.0])), "added_mass", "6x6",
                 id="added-mass-short-row"),
    pytest.param(put("added_mass", MA[:5]), "added_mass", "6x6", id="added-mass-five-rows"),
    pytest.param(put("added_mass", with_row(MA, 0, [NAN, 0.0, 0.0, 0.0, 0.0, 0.0])), "added_mass", "finite",
                 id="added-mass-nan"),
    pytest.param(put("added_mass", with_row(MA, 0, [15.0, 3.0, 0.0, 0.0, 0.0, 0.0])), "added_mass", "symmetric",
                 id="added-mass-asymmetric"),
    pytest.param(put("added_mass", with_row(MA, 0, [-15.0, 0.0, 0.0, 0.0, 0.0, 0.0])), "added_mass",
                 "semi-definite", id="added-mass-sign-convention"),
    pytest.param(put("added_mass", with_row(MA, 5, [0.0, 4.0, 0.0, 0.0, 0.0, 1e300])), "added_mass",
                 "condition number", id="added-mass-1e300"),
    # thrusters: non-zero finite directions, non-negative coefficients, own names and own signals
    pytest.param(put("thrusters.2.direction", [0.0, 0.0, 0.0]), "thrusters.2.direction", "non-zero",
                 id="direction-zero"),
    pytest.param(put("thrusters.0.direction", [NAN, 0.0, 0.0]), "thrusters.0.direction", "finite",
                 id="direction-nan"),
    pytest.param(put("thrusters.0.direction", [INF, 0.0, 0.0]), "thrusters.0.direction", "finite",
                 id="direction-inf"),
    pytest.param(put("thrusters.0.direction", [1.0, 0.0]), "thrusters.0.direction", "", id="direction-2d"),
    pytest.param(put("thrusters.0.thrust.k_fwd_N_per_rpm2", -4.1e-6), "thrusters.0.thrust.k_fwd_N_per_rpm2",
                 "greater than or equal", id="k-fwd-negative"),
    pytest.param(put("thrusters.1.thrust.k_bwd_N_per_rpm2", -3.3e-6), "thrusters.1.thrust.k_bwd_N_per_rpm2",
                 "greater than or equal", id="k-bwd-negative"),
    pytest.param(put("thrusters.1.name", "th1"), "thrusters.1.name", "unique", id="thruster-name-twice"),
    pytest.param(put("thrusters.4.speed_signal", "n1_rpm"), "thrusters.4.speed_signal", "own input signal",
                 id="speed-signal-twice"),
    pytest.param(put("thrusters.0.speed_signal", "n9_rpm"), "thrusters.0.speed_signal", "not a configured signal",
                 id="speed-signal-undefined"),
    pytest.param(put("thrusters.0.name", "../th1"), "thrusters.0.name", "pattern", id="thruster-name-path"),
    pytest.param(put("thrusters.0.lag_s", -0.1), "thrusters.0.lag_s", "greater than or equal", id="lag-negative"),
    pytest.param(put("thrusters", []), "thrusters", "at least 1", id="no-thrusters"),
    # sensors: every signal named is defined by a stream
    pytest.param(put("sensors.dvl.valid", "dvl_lock_flag"), "sensors.dvl.valid", "not a configured signal",
                 id="validity-signal-undefined"),
    pytest.param(put("sensors.rates.r", "r_gyro_radps"), "sensors.rates.r", "not a configured signal",
                 id="rate-signal-undefined"),
    pytest.param(put("sensors.dvl.velocity", ["dvl_x_mps", "dvl_y_mps", "dvl_w_mps"]), "sensors.dvl.velocity.2",
                 "not a configured signal", id="dvl-signal-undefined"),
    pytest.param(put("sensors.depth", "depth_ft"), "sensors.depth", "not a configured signal",
                 id="depth-signal-undefined"),
    pytest.param(move_signal("depth_m", "depth", "dvl"), "streams.dvl.signals.depth_m", "more than one stream",
                 id="signal-in-two-streams"),
    # streams: finite, sane clock offsets; known units; names safe as file names
    pytest.param(put("streams.ahrs.offset_s", 1e300), "streams.ahrs.offset_s", "cannot be meant",
                 id="offset-1e300"),
    pytest.param(put("streams.ahrs.offset_s", NAN), "streams.ahrs.offset_s", "finite", id="offset-nan"),
    pytest.param(put("streams.ahrs.offset_s", -INF), "streams.ahrs.offset_s", "finite", id="offset-minus-inf"),
    pytest.param(put("streams.ahrs.offset_s", False), "streams.ahrs.offset_s", "boolean", id="offset-false"),
    pytest.param(put("streams.dvl.signals.dvl_x_mps.unit", "furlong/fortnight"),
                 "streams.dvl.signals.dvl_x_mps.unit", "furlong", id="unit-unknown"),
    pytest.param(put("streams.fog.signals", {"r_fog": {"field": "vector.z"}}), "streams.fog.signals.r_fog",
                 "unit suffix", id="signal-without-unit-suffix"),
    pytest.param(rename_stream("dvl", "../../../../tmp/x"), "streams.../../../../tmp/x", "not a safe name",
                 id="stream-name-escapes"),
    pytest.param(rename_stream("dvl", ".."), "streams...", "not a safe name", id="stream-name-dotdot"),
    pytest.param(rename_stream("dvl", ".hidden"), "streams..hidden", "not a safe name", id="stream-name-hidden"),
    pytest.param(add_csv_stream(encoding="klingon"), "streams.tank.csv.encoding", "unknown text encoding",
                 id="csv-encoding-unknown"),
    pytest.param(add_csv_stream(time_origin="relative", epoch_s=1e300), "streams.tank.csv.epoch_s",
                 "cannot be meant", id="csv-epoch-1e300"),
    pytest.param(add_csv_stream(skip_rows=True), "streams.tank.csv.skip_rows", "boolean", id="csv-skip-rows-true"),
    pytest.param(put("streams.fog.time", {"rate_hz": 0.0}), "streams.fog.time.rate_hz", "greater than 0",
                 id="stream-rate-zero"),
    pytest.param(put("trials", {"dive1": {"streams": {"ahrs": {"offset_s": 1e300}}}}), "trials",
                 "cannot be meant", id="trial-offset-1e300"),
    pytest.param(put("trials", {"dive1": {"streams": {"gps": {"offset_s": 0.1}}}}), "trials", "no stream 'gps'",
                 id="trial-override-unknown-stream"),
]


def _write(tmp_path: Path, data: bytes | str, name: str = "vehicle.yaml") -> Path:
    path = tmp_path / name
    if isinstance(data, str):
        path.write_text(data, encoding="utf-8")
    else:
        path.write_bytes(data)
    return path


def _refused(load: Callable[[Path], Any], path: Path) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        load(path)
    err = info.value
    assert err.file == str(path) and str(path) in str(err), f"the error does not name the file: {err}"
    assert "Traceback" not in str(err) and "<unicode string>" not in str(err)
    return err


def test_the_example_vehicle_loads(tmp_path: Path) -> None:
    assert load_vehicle(DAGON).name == "dagon"
    doc = copy.deepcopy(BASE)
    add_csv_stream(encoding="cp1252", time_origin="relative", epoch_s=1.7e9)(doc)
    assert load_vehicle(_write(tmp_path, yaml.safe_dump(doc))).streams["tank"].csv.epoch_s == 1.7e9


@pytest.mark.parametrize(("edit", "field", "says"), VEHICLE_CASES)
def test_malformed_vehicle_is_refused_naming_file_and_key(tmp_path: Path, edit: Edit, field: str, says: str
                                                          ) -> None:
    doc = copy.deepcopy(BASE)
    edit(doc)
    err = _refused(load_vehicle, _write(tmp_path, yaml.safe_dump(doc, sort_keys=False)))
    assert err.field is not None and err.field.startswith(field), f"field {err.field!r}, expected {field!r}: {err}"
    assert f"field {err.field!r}" in str(err)
    assert says in str(err), f"{says!r} not in: {err}"


@pytest.mark.parametrize(("inertia", "says"), [
    pytest.param(with_row(I3, 0, [-5.0, 0.0, 0.0]), "positive definite", id="negative-diagonal"),
    pytest.param(with_row(I3, 0, [5.0, 1.0, 0.0]), "symmetric", id="asymmetric"),
    pytest.param(with_row(I3, 2, [0.0, 0.0, NAN]), "finite", id="nan"),
])
def test_the_rigid_body_alone_refuses_a_bad_inertia(inertia: list[list[float]], says: str) -> None:
    """The rigid body's own check (the vehicle's mass-matrix check would catch these too, through physics)."""
    from pipeline.config import parse
    from pipeline.config.rigid_body import RigidBody

    with pytest.raises(ConfigError) as info:
        parse(RigidBody, {**BASE["rigid_body"], "inertia_kgm2": inertia}, "rigid_body.yaml")
    assert info.value.field.startswith("inertia_kgm2") and says in str(info.value)


def _line_of(text: str, needle: str) -> int:
    return text[: text.index(needle)].count("\n") + 1


def _alias_bomb() -> str:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 9)]
    return "\n".join(lines) + "\n"


DUPLICATE_NESTED = TEXT.replace("  mass_kg: 75.0\n", "  mass_kg: 75.0\n  cg_m: [0, 0, 0]\n  mass_kg: 7.5\n")

TEXT_CASES = [
    pytest.param(TEXT + "name: dagon2\n", "name",
                 [f"duplicate key 'name' at line {TEXT.count(chr(10)) + 1} (first at line {_line_of(TEXT, 'name:')})"],
                 id="duplicate-top-level-key"),
    pytest.param(DUPLICATE_NESTED, "rigid_body.mass_kg",
                 [f"duplicate key 'mass_kg' at line {_line_of(DUPLICATE_NESTED, '  mass_kg: 7.5')}",
                  f"first at line {_line_of(DUPLICATE_NESTED, '  mass_kg: 75.0')}"], id="duplicate-nested-key"),
    pytest.param(TEXT.replace("    offset_s: 0.05 ", "    offset_s: 0.05\n    offset_s: 0.0 "), "streams.dvl.offset_s",
                 ["duplicate key 'offset_s'"], id="duplicate-stream-key"),
    pytest.param(("# Dagon, DFKI Bremen (M\u00fcller)\n" + TEXT).encode("latin-1"), None,
                 ["not UTF-8: byte 0xfc at offset 23 (line 1)", "save it as UTF-8"], id="latin-1"),
    pytest.param(TEXT.encode("utf-16"), None, ["UTF-16", "save it as UTF-8"], id="utf-16"),
    pytest.param(TEXT.encode("utf-8") + b"\n# \xff\xfe\n", None,
                 ["not UTF-8: byte 0xff", f"(line {TEXT.count(chr(10)) + 2})"], id="stray-byte"),
    pytest.param("name: " + "[" * 5000 + "]" * 5000 + "\n", None, ["nested too deeply", "line 1"],
                 id="nested-5000-deep"),
    pytest.param(_alias_bomb(), None, ["expands to more than"], id="alias-bomb"),
    pytest.param("name: &x [*x]\n", None, ["expands to more than"], id="alias-to-itself"),
    pytest.param("name: [dagon\nrigid_body: {}\n", None, ["not valid YAML at line 2, column 11"],
                 id="unclosed-bracket"),
    pytest.param("name: dagon\n\tmass: 1\n", None, ["not valid YAML at line 2, column 1"], id="tab-indent"),
    pytest.param("name: dagon\nx: da\x00gon\n", None, ["not valid YAML at line 2", "#x0000 is not allowed"],
                 id="nul-byte"),
    pytest.param("# " + "\u00fc" * 20 + "\nx: da\x00gon\nname: dagon\nmore: 1\n", None,
                 ["not valid YAML at line 2:"], id="nul-byte-after-non-ascii"),
    pytest.param("name: !!python/object/apply:os.system [echo]\n", None, ["not valid YAML at line 1",
                                                                          "could not determine a constructor"],
                 id="python-tag"),
]


@pytest.fixture(params=["libyaml", "pure-python"])
def yaml_parser(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Each YAML case through libyaml's parser (the default where PyYAML has it) and through PyYAML's pure-Python
    one (the fallback where it does not): the same refusals, the same messages and lines."""
    from pipeline.config import yamlload

    if request.param == "libyaml":
        if not yaml.__with_libyaml__:
            pytest.fail("PyYAML without libyaml: the install should have its wheel, which has it")
        assert yamlload._Loader is yaml.CSafeLoader  # the default where libyaml is there
    else:
        monkeypatch.setattr(yamlload, "_Loader", yaml.SafeLoader)
    return request.param


@pytest.mark.parametrize(("data", "field", "says"), TEXT_CASES)
def test_unreadable_yaml_is_a_config_error_naming_file_and_line(tmp_path: Path, data: str | bytes,
                                                                field: str | None, says: list[str],
                                                                yaml_parser: str) -> None:
    err = _refused(load_vehicle, _write(tmp_path, data))
    assert err.field == field
    for text in says:
        assert text in str(err), f"{text!r} not in: {err}"


def test_running_out_of_stack_while_building_the_values_is_a_config_error(tmp_path: Path, yaml_parser: str,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """Python's recursion limit met past the parser (libyaml's loader has no position to give then): still the
    "nested too deeply" ConfigError naming the file, never a traceback."""
    from pipeline.config import yamlload

    def too_deep(self: Any, node: Any) -> Any:
        raise RecursionError("maximum recursion depth exceeded")

    monkeypatch.setattr(yamlload._Loader, "construct_document", too_deep)
    err = _refused(load_vehicle, _write(tmp_path, "name: [[1]]\n"))
    assert "nested too deeply" in str(err) and "vehicle.yaml" in str(err)


def test_merge_keys_may_be_overridden(tmp_path: Path) -> None:
    """``<<: *anchor`` then a key of the anchor: YAML's override, not a duplicate."""
    text = TEXT.replace("  - name: th2\n", "  - &second\n    name: th2\n").replace(
        "  - name: th3\n    speed_signal: n3_rpm\n", "  - <<: *second\n    name: th3\n    speed_signal: n3_rpm\n")
    assert load_vehicle(_write(tmp_path, text)).thrusters[2].name == "th3"


def test_a_config_error_raised_inside_a_validator_gets_the_file() -> None:
    from pydantic import field_validator

    from pipeline.config import parse
    from pipeline.config.base import Frozen

    class Model(Frozen):
        x: float

        @field_validator("x")
        @classmethod
        def _helper_raises(cls, x: float) -> float:
            raise ConfigError("a helper's own error", field="x")

    with pytest.raises(ConfigError) as info:
        parse(Model, {"x": 1.0}, "model.yaml")
    assert info.value.file == "model.yaml" and info.value.field == "x"


def test_a_utf8_byte_order_mark_is_fine(tmp_path: Path) -> None:
    assert load_vehicle(_write(tmp_path, b"\xef\xbb\xbf" + TEXT.encode("utf-8"))).name == "dagon"


def test_a_unit_unknown_names_file_and_signal(tmp_path: Path) -> None:
    path = _write(tmp_path, TEXT.replace("dvl_y_mps: {field: velocity.y, unit: m/s}",
                                         "dvl_y_mps: {field: velocity.y, unit: knots/s}"))
    err = _refused(load_vehicle, path)
    assert err.field == "streams.dvl.signals.dvl_y_mps.unit" and "knots/s" in str(err)


def test_a_directions_length_is_free_and_normalized_by_physics() -> None:
    """Chosen: any non-zero direction is accepted and normalized ([1, 1, 0] is 45 degrees)."""
    from pipeline import physics
    from pipeline.config import parse
    from pipeline.config.vehicle import Vehicle

    doc = copy.deepcopy(BASE)
    doc["thrusters"][2]["direction"] = [0.0, 2.0, 0.0]
    scaled = physics.allocation_matrix(parse(Vehicle, doc))
    assert scaled.tolist() == physics.allocation_matrix(parse(Vehicle, BASE)).tolist()


PARAMS_CASES = [
    pytest.param({"features": {"test_trials": ["../../etc"]}}, "features.test_trials.0", "not a safe name",
                 id="test-trial-path"),
    pytest.param({"features": {"test_trials": [".."]}}, "features.test_trials.0", "not a safe name",
                 id="test-trial-dotdot"),
    pytest.param({"features": {"test_trials": ["trial03", "trial03"]}}, "features.test_trials.1", "twice",
                 id="test-trial-twice"),
    pytest.param({"features": {"tuning_fraction": NAN}}, "features.tuning_fraction", "finite",
                 id="tuning-fraction-nan"),
    pytest.param({"coupled": {"models": ["rbf_svr", "nope"]}}, "coupled.models.1", "unknown coupled model",
                 id="coupled-model-unknown"),
    pytest.param({"decoupled": {"models": ["../../tmp/gp"]}}, "decoupled.models.0", "unknown decoupled model",
                 id="decoupled-model-path"),
    pytest.param({"decoupled": {"dofs": ["u", "x"]}}, "decoupled.dofs.1", "unknown DOF", id="decoupled-dof"),
    pytest.param({"decoupled": {"trials": {"x": ["trial01"]}}}, "decoupled.trials.x", "not a DOF",
                 id="decoupled-trials-dof"),
    pytest.param({"decoupled": {"trials": {"u": ["trial01", "../x"]}}}, "decoupled.trials.u.1", "not a safe name",
                 id="decoupled-trials-path"),
    pytest.param({"simulate": {"models": ["rbf_svr"]}}, "simulate.models.0", "unknown decoupled model",
                 id="simulate-model-unknown"),
    pytest.param({"differentiate": {"process_noise": {"z": 1.0}}}, "differentiate.process_noise.z", "not a DOF",
                 id="process-noise-dof"),
    pytest.param({"differentiate": {"noise_sd": {"dvl_x_mps": 0.0}}}, "differentiate.noise_sd.dvl_x_mps",
                 "greater than or equal to 0.000000001", id="noise-sd-zero"),
    pytest.param({"sync": {"rate_hz": INF}}, "sync.rate_hz", "finite", id="rate-inf"),
    pytest.param({"sync": {"rate_hz": True}}, "sync.rate_hz", "boolean", id="rate-true"),
    pytest.param({"sync": {"max_gap_s": {"default": -1.0}}}, "sync.max_gap_s.default", "greater than or equal",
                 id="max-gap-negative"),
    pytest.param({"coupled": {"folds": True}}, "coupled.folds", "boolean", id="folds-true"),
    # values that reached a traceback at their stage, or ran on with nonsense (issue 36, item 3)
    pytest.param({"sync": {"rate_hz": 1e9}}, "sync.rate_hz", "less than or equal to 1000", id="rate-1e9"),
    pytest.param({"sync": {"max_gap_s": {"default": 1e300}}}, "sync.max_gap_s.default", "less than or equal",
                 id="max-gap-1e300"),
    pytest.param({"differentiate": {"method": "gaussian", "sigma_s": 0}}, "differentiate.sigma_s",
                 "positive number of seconds", id="sigma-zero"),
    pytest.param({"differentiate": {"method": "gaussian", "sigma_s": -1}}, "differentiate.sigma_s",
                 "positive number of seconds", id="sigma-negative"),
    pytest.param({"differentiate": {"savgol_window_s": 0}}, "differentiate.savgol_window_s",
                 "positive number of seconds", id="savgol-window-zero"),
    pytest.param({"differentiate": {"savgol_order": 100}}, "differentiate.savgol_order", "less than or equal to 7",
                 id="savgol-order-100"),
    pytest.param({"differentiate": {"max_velocity_sd_mps": 1e300}}, "differentiate.max_velocity_sd_mps",
                 "less than or equal to 10", id="max-velocity-sd-1e300"),
    pytest.param({"features": {"tuning_fraction": 0.99999}}, "features.tuning_fraction", "less than or equal to 0.9",
                 id="tuning-fraction-all"),
    pytest.param({"coupled": {"max_samples": -5}}, "coupled.max_samples", "greater than or equal",
                 id="max-samples-negative"),
    pytest.param({"coupled": {"seed": -1}}, "coupled.seed", "greater than or equal to 0", id="coupled-seed-negative"),
    pytest.param({"coupled": {"seed": 2**70}}, "coupled.seed", "less than or equal to 4294967295",
                 id="coupled-seed-huge"),
    pytest.param({"coupled": {"n_jobs": 0}}, "coupled.n_jobs", "-1 or auto for all cores", id="n-jobs-zero"),
    pytest.param({"coupled": {"n_jobs": -1000}}, "coupled.n_jobs", "-1 or auto for all cores", id="n-jobs-minus-1000"),
    pytest.param({"coupled": {"models": []}}, "coupled.models", "at least 1 item", id="coupled-models-empty"),
    pytest.param({"decoupled": {"seed": -1}}, "decoupled.seed", "greater than or equal to 0",
                 id="decoupled-seed-negative"),
    pytest.param({"decoupled": {"curve_points": 10**6}}, "decoupled.curve_points", "less than or equal to 50",
                 id="curve-points-1e6"),
    pytest.param({"simulate": {"outage_windows_s": [0]}}, "simulate.outage_windows_s.0", "greater than 0",
                 id="outage-window-zero"),
    pytest.param({"simulate": {"band_samples": 10**9}}, "simulate.band_samples", "less than or equal to 1000",
                 id="band-samples-1e9"),
    pytest.param({"simulate": {"seed": -1}}, "simulate.seed", "greater than or equal to 0", id="simulate-seed"),
    pytest.param({"simulate": {"horizons_s": []}}, "simulate.horizons_s", "at least 1 item", id="horizons-empty"),
    pytest.param({"simulate": {"horizons_s": [-1]}}, "simulate.horizons_s.0", "greater than 0",
                 id="horizon-negative"),
    pytest.param({"simulate": {"horizons_s": [1e9]}}, "simulate.horizons_s.0", "less than or equal to 86400",
                 id="horizon-1e9"),
    # the rest of issue 36's item 3: numbers that loaded and gave nonsense or a traceback at their stage
    pytest.param({"differentiate": {"gate_sigmas": 1e142}}, "differentiate.gate_sigmas", "less than or equal to 100",
                 id="gate-1e142"),
    pytest.param({"sync": {"min_segment_s": 1e9}}, "sync.min_segment_s", "less than or equal to 86400",
                 id="sync-min-segment-1e9"),
    pytest.param({"differentiate": {"min_segment_s": 1e9}}, "differentiate.min_segment_s",
                 "less than or equal to 86400", id="kalman-min-segment-1e9"),
    pytest.param({"simulate": {"divergence_factor": 2**64}}, "simulate.divergence_factor",
                 "less than or equal to 1000", id="divergence-2-64"),
    pytest.param({"differentiate": {"edge_sigmas": 1e300}}, "differentiate.edge_sigmas", "less than or equal to 10",
                 id="edge-sigmas-1e300"),
    pytest.param({"differentiate": {"noise_sd": {"dvl_x_mps": 1e300}}}, "differentiate.noise_sd.dvl_x_mps",
                 "less than or equal to 1000000", id="noise-sd-1e300"),
    pytest.param({"differentiate": {"process_noise": {"u": 5e-324}}}, "differentiate.process_noise.u",
                 "greater than or equal to 0.000000000001", id="process-noise-denormal"),
    pytest.param({"differentiate": {"sigma_s_per_signal": {"u_mps": 1e9}}}, "differentiate.sigma_s_per_signal.u_mps",
                 "less than or equal to 3600", id="sigma-per-signal-1e9"),
    pytest.param({"differentiate": {"notch_hz": [1e-300]}}, "differentiate.notch_hz.0",
                 "greater than or equal to 0.001", id="notch-1e-300"),
    pytest.param({"differentiate": {"notch_hz": [12.0]}}, "differentiate.notch_hz.0", "Nyquist frequency 10 Hz",
                 id="notch-above-nyquist"),
    pytest.param({"differentiate": {"notch_width_hz": 1e-300}}, "differentiate.notch_width_hz",
                 "greater than or equal to 0.001", id="notch-width-1e-300"),
    pytest.param({"differentiate": {"max_hz": 1e-300}}, "differentiate.max_hz", "greater than or equal to 0.001",
                 id="max-hz-1e-300"),
    pytest.param({"sync": {"rate_hz": 4.0}, "differentiate": {"max_hz": 2.0}}, "differentiate.max_hz",
                 "Nyquist frequency 2 Hz", id="max-hz-at-nyquist"),
    pytest.param({"coupled": {"screen_samples": 2**70}}, "coupled.screen_samples", "less than or equal to 1000000",
                 id="screen-samples-2-70"),
    pytest.param({"coupled": {"screen_folds": 10**9}}, "coupled.screen_folds", "less than or equal to 100",
                 id="screen-folds-1e9"),
    pytest.param({"coupled": {"survivors": 2**63}}, "coupled.survivors", "less than or equal to 10000",
                 id="survivors-2-63"),
    pytest.param({"coupled": {"fold_evals": 2**63}}, "coupled.fold_evals", "less than or equal to 10000",
                 id="fold-evals-2-63"),
    pytest.param({"coupled": {"refine_horizon_s": 1e300}}, "coupled.refine_horizon_s", "less than or equal to 3600",
                 id="refine-horizon-1e300"),
    pytest.param({"coupled": {"smooth_tolerance": 1e300}}, "coupled.smooth_tolerance", "less than or equal to 1",
                 id="smooth-tolerance-1e300"),
    pytest.param({"coupled": {"inputs": []}}, "coupled.inputs", "at least 1 item", id="coupled-inputs-empty"),
    pytest.param({"coupled": {"outputs": []}}, "coupled.outputs", "at least 1 item", id="coupled-outputs-empty"),
    pytest.param({"decoupled": {"dofs": []}}, "decoupled.dofs", "at least 1 item", id="decoupled-dofs-empty"),
    pytest.param({"decoupled": {"models": []}}, "decoupled.models", "at least 1 item", id="decoupled-models-empty"),
]


def test_the_bounds_admit_what_users_give() -> None:
    """The bounds refuse nonsense, not settings: all cores, auto widths, a 1-kHz grid, no bridging windows."""
    from pipeline.config.params import Params

    ok = Params.model_validate({"sync": {"rate_hz": 1000.0, "max_gap_s": {"default": 0.0}, "min_segment_s": 0.0},
                                "differentiate": {"sigma_s": "auto", "savgol_window_s": 0.05, "gate_sigmas": 100.0,
                                                  "notch_hz": [0.001, 499.0], "max_hz": 499.9,
                                                  "noise_sd": {"n1_rpm": 50.0}, "process_noise": {"u": 1e-9}},
                                "coupled": {"n_jobs": -1, "seed": 2**32 - 1, "max_samples": None},
                                "simulate": {"outage_windows_s": [], "horizons_s": [86_400.0],
                                             "divergence_factor": 1000.0}})
    assert ok.coupled.n_jobs == -1 and ok.simulate.outage_windows_s == []


@pytest.mark.parametrize(("doc", "field", "says"), PARAMS_CASES)
def test_malformed_params_are_refused_naming_file_and_key(tmp_path: Path, doc: dict[str, Any], field: str,
                                                          says: str) -> None:
    err = _refused(load_params, _write(tmp_path, yaml.safe_dump(doc), "params.yaml"))
    assert err.field == field, f"field {err.field!r}, expected {field!r}: {err}"
    assert says in str(err), f"{says!r} not in: {err}"


def test_the_model_names_params_accept_are_the_pipelines() -> None:
    """params.py keeps its own lists (loading params must not import the modelling stack); they must not drift."""
    from pipeline.config.params import COUPLED_MODELS, DECOUPLED_MODELS
    from pipeline.models.decoupled import MODEL_NAMES
    from pipeline.models.search import SVR_MODELS
    from pipeline.studies.coupled import EXPLICIT_MODELS, GRAYBOX_MODELS

    assert set(COUPLED_MODELS) == {*SVR_MODELS, *EXPLICIT_MODELS, *GRAYBOX_MODELS}
    assert set(DECOUPLED_MODELS) == set(MODEL_NAMES)


def test_loading_params_imports_no_modelling_stack() -> None:
    code = ("import sys\nfrom pipeline.config import load_params\nload_params('params.yaml')\n"
            "print(sorted(m for m in ('pandas', 'scipy', 'sklearn', 'joblib') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_params_duplicate_key_is_refused(tmp_path: Path) -> None:
    path = _write(tmp_path, "features:\n  test_trials: [trial01]\n  test_trials: [trial02]\n", "params.yaml")
    err = _refused(load_params, path)
    assert err.field == "features.test_trials" and "line 3 (first at line 2)" in str(err)


def test_repository_params_load() -> None:
    assert load_params(ROOT / "params.yaml").features.test_trials == ["trial03"]


def test_cli_exits_2_without_traceback_on_a_latin1_vehicle(tmp_path: Path) -> None:
    path = _write(tmp_path, ("# M\u00fcller\n" + TEXT).encode("latin-1"))
    log = _write(tmp_path, b"", "run01.csv")
    proc = subprocess.run([sys.executable, "-m", "pipeline.cli", "ingest", "--root", str(tmp_path / "run"),
                           "--vehicle", str(path), str(log)], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert str(path) in proc.stderr and "not UTF-8" in proc.stderr


def test_test_trials_must_name_a_trial_of_the_run(tmp_path: Path) -> None:
    """A ROS 2 bag directory trial_test_ros2 is trial 'trial_test_ros2': test_trials [trial_test] matches nothing,
    which must stop the features stage instead of letting the test trial join tuning and training."""
    from pipeline.config import Params
    from stages import features

    (tmp_path / "data" / "derived").mkdir(parents=True)
    (tmp_path / "data" / "derived" / "trial01.parquet").write_bytes(b"")
    (tmp_path / "data" / "raw" / "trial_test_ros2").mkdir(parents=True)
    params = Params.model_validate({"features": {"test_trials": ["trial_test"]}})
    with pytest.raises(ConfigError) as info:
        features.run(tmp_path, load_vehicle(DAGON), params)
    assert info.value.field == "features.test_trials"
    assert "['trial_test']" in str(info.value) and "['trial01', 'trial_test_ros2']" in str(info.value)


def test_a_quarantined_test_trial_is_a_warning(caplog: pytest.LogCaptureFixture) -> None:
    from pipeline import store
    from pipeline.config.params import FeaturesParams

    chosen = store.check_test_trials(FeaturesParams(test_trials=["trial02", "trial03"]), ["trial01", "trial03"],
                                     {"trial01", "trial02", "trial03"})
    assert chosen == ["trial03"]
    assert "test trial trial02 has no derived table" in caplog.text


@pytest.mark.parametrize(("differentiate", "says"), [
    ({"noise_sd": {"dvl_x_mp": 0.02}}, r"differentiate.noise_sd names \['dvl_x_mp'\], which are not signals"),
    ({"sigma_s_per_signal": {"dvl_x_mps": 0.3}}, r"sigma_s_per_signal names \['dvl_x_mps'\], which are not velocity"),
])
def test_params_naming_signals_the_vehicle_lacks_are_refused(tmp_path: Path, differentiate: dict[str, Any],
                                                             says: str) -> None:
    """A misspelt noise_sd key was ignored, the noise estimated from the data without a word."""
    from stages.common import load_configs

    params = _write(tmp_path, yaml.safe_dump({"differentiate": differentiate}), "params.yaml")
    with pytest.raises(ConfigError, match=says) as err:
        load_configs(tmp_path, DAGON, params)
    assert str(params) in str(err.value)
    ok = _write(tmp_path, yaml.safe_dump({"differentiate": {"noise_sd": {"dvl_x_mps": 0.02},
                                                            "sigma_s_per_signal": {"u_mps": 0.3}}}), "ok.yaml")
    assert load_configs(tmp_path, DAGON, ok)[1].differentiate.noise_sd == {"dvl_x_mps": 0.02}


@pytest.mark.parametrize(("sync", "field"), [
    ({"max_gap_s": {"default": 0.5, "x": 0.2}}, "sync.max_gap_s.x"),
    ({"interpolation": {"dvl_x_mp": "zoh"}}, "sync.interpolation.dvl_x_mp"),
])
def test_sync_settings_naming_signals_the_vehicle_lacks_are_refused_with_the_params_file(
        tmp_path: Path, sync: dict[str, Any], field: str) -> None:
    """Found by the run campaign (seed 3911): the sync stage refused a per-signal key that names no signal with exit
    2, but without the params file; it is refused when the configs load, naming file and key."""
    from stages.common import load_configs

    params = _write(tmp_path, yaml.safe_dump({"sync": sync}), "params.yaml")
    with pytest.raises(ConfigError, match="which are not signals of the vehicle's streams") as err:
        load_configs(tmp_path, DAGON, params)
    assert err.value.file == str(params) and err.value.field == field
    ok = _write(tmp_path, yaml.safe_dump({"sync": {"max_gap_s": {"default": 0.5, "dvl_x_mps": 0.3},
                                                   "interpolation": {"n1_rpm": "zoh"}}}), "ok.yaml")
    assert load_configs(tmp_path, DAGON, ok)[1].sync.max_gap_s["dvl_x_mps"] == 0.3


def test_thrust_inputs_of_thrusters_the_vehicle_lacks_are_said_when_the_configs_load(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The default coupled.inputs name DAGON's thrust columns (T_th1_N ...): a vehicle whose thrusters have other
    names hears it when the configs load, before ingest ... features run, not only at the tune stage. A warning:
    a run whose params train no model taking coupled.inputs says nothing."""
    from stages.common import load_configs

    renamed = _write(tmp_path, TEXT.replace("name: th1\n", "name: port\n"), "vehicle.yaml")
    params = _write(tmp_path, "{}\n", "params.yaml")
    load_configs(tmp_path, renamed, params)
    assert "coupled.inputs names ['T_th1_N'], thrust columns of thrusters the vehicle" in caplog.text
    assert "'T_port_N', 'T_th2_N'" in caplog.text and str(params) in caplog.text
    caplog.clear()
    load_configs(tmp_path, DAGON, params)
    explicit = _write(tmp_path, yaml.safe_dump({"coupled": {"models": ["gertler_hagen", "mcfarland_whitcomb"]}}),
                      "explicit.yaml")
    load_configs(tmp_path, renamed, explicit)
    assert "coupled.inputs" not in caplog.text
