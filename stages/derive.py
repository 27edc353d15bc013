"""Derive stage: data/kinematics/<trial>.parquet -> data/derived/<trial>.parquet (thrust, tau, damping target) and
<trial>.spectra.json (each target's spectrum against its inputs': pipeline.estimation.spectral)."""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import layout
from pipeline.config import Params, Vehicle
from pipeline.config.vehicle import thrust_column
from pipeline.derive import derive
from pipeline.errors import SchemaError, SyncError
from pipeline.estimation.spectral import check_targets, report_path
from pipeline.tableio import read_parquet, remove_stale_temps, write_json, write_parquet
from stages._pertrial import add_trial_argument, drop_stale, provenance, quarantine, shown, to_arrow, trials_in
from stages.common import StageResult, stage_main

NAME = "derive"
log = logging.getLogger(__name__)


def run(root: Path, vehicle: Vehicle, params: Params, trial: str | None = None) -> StageResult:
    """Per-thruster thrust, generalized forces, M nu_dot, C(nu) nu, g(eta) and the damping target."""
    root = Path(root)
    result = StageResult(stage=NAME)
    remove_stale_temps(root / layout.DERIVED,
                       targets=None if trial is None else {f"{trial}.parquet", f"{trial}.spectra.json"})
    for name in trials_in(root / layout.KINEMATICS, trial):
        source = layout.kinematics_path(root, name)
        target = layout.derived_path(root, name)
        try:
            if not source.exists():
                raise SyncError("no kinematics table (run the differentiate stage)", file=shown(source, root))
            frame = derive(read_parquet(source)[0].to_pandas(), vehicle)
            # every target against its inputs: tau per DOF, else the thrusts and actuator signals (a rudder)
            spectra = check_targets(frame, name, [*(thrust_column(t.name) for t in vehicle.thrusters),
                                                   *vehicle.actuator_signals()])
        except (SyncError, SchemaError) as err:
            result.quarantined.append(quarantine(err, name, shown(source, root)))
            drop_stale(target)
            drop_stale(report_path(root, name))
            continue
        # derive uses the vehicle (mass, thrusters) and no params section: the config hash covers it
        write_parquet(to_arrow(frame), target, provenance(root, NAME, name, [source], vehicle, None))
        write_json(spectra, report_path(root, name))  # a report beside the table, not counted among its outputs
        result.outputs.append(target)
        result.summary[name] = {"samples": len(frame), "spectral_warnings": len(spectra["warnings"])}
        log.info("derive %s: %d samples", name, len(frame))
    return result


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv, extra=add_trial_argument)


if __name__ == "__main__":
    raise SystemExit(main())
