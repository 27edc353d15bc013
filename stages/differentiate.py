"""Differentiate stage: data/synced/<trial>.parquet -> data/kinematics/<trial>.parquet (body frame, nu_dot)."""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import layout
from pipeline.config import Params, Vehicle
from pipeline.errors import SchemaError, SyncError
from pipeline.kinematics import kinematics
from pipeline.tableio import read_parquet, write_parquet
from stages._pertrial import add_trial_argument, drop_stale, provenance, quarantine, shown, to_arrow, trials_in
from stages.common import StageResult, stage_main

NAME = "differentiate"
log = logging.getLogger(__name__)


def run(root: Path, vehicle: Vehicle, params: Params, trial: str | None = None) -> StageResult:
    """Body velocities and attitude, then smoothed velocities and accelerations per segment, edges trimmed."""
    root = Path(root)
    result = StageResult(stage=NAME)
    for name in trials_in(root / layout.SYNCED, trial):
        source = layout.synced_path(root, name)
        target = layout.kinematics_path(root, name)
        try:
            if not source.exists():
                raise SyncError("no synced table (run the sync stage)", file=shown(source, root))
            frame = kinematics(read_parquet(source)[0].to_pandas(), vehicle, params.differentiate)
        except (SyncError, SchemaError) as err:
            result.quarantined.append(quarantine(err, name, shown(source, root)))
            drop_stale(target)
            continue
        write_parquet(to_arrow(frame), target, provenance(root, NAME, name, [source], vehicle, params.differentiate))
        result.outputs.append(target)
        result.summary[name] = {"samples": len(frame)}
        log.info("differentiate %s: %d samples kept", name, len(frame))
    return result


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv, extra=add_trial_argument)


if __name__ == "__main__":
    raise SystemExit(main())
