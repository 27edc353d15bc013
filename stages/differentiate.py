"""Differentiate stage: data/synced/<trial>.parquet (+ the trial's native streams in data/signals/<trial>/) ->
data/kinematics/<trial>.parquet (body frame, nu, nu_dot and their SDs) and <trial>.estimation.json (noise per
signal, the smoother's process noise and gating, or the filter widths; how much of the trial is usable)."""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import layout
from pipeline.config import Params, Vehicle
from pipeline.errors import SchemaError, SyncError
from pipeline.estimation.differentiate import differentiate
from pipeline.tableio import read_parquet, remove_stale_temps, write_json, write_parquet
from stages._pertrial import add_trial_argument, drop_stale, provenance, quarantine, shown, to_arrow, trials_in
from stages.common import StageResult, stage_main

NAME = "differentiate"
log = logging.getLogger(__name__)


def run(root: Path, vehicle: Vehicle, params: Params, trial: str | None = None) -> StageResult:
    """Body velocities and attitude, then smoothed velocities and accelerations per segment, edges trimmed."""
    root = Path(root)
    result = StageResult(stage=NAME)
    remove_stale_temps(root / layout.KINEMATICS,
                       targets=None if trial is None else {f"{trial}.parquet", f"{trial}.estimation.json"})
    for name in trials_in(root / layout.SYNCED, trial):
        source = layout.synced_path(root, name)
        target = layout.kinematics_path(root, name)
        try:
            if not source.exists():
                raise SyncError("no synced table (run the sync stage)", file=shown(source, root))
            stream_files = sorted(p for p in layout.signals_dir(root, name).glob("*.parquet")
                                  if not p.name.startswith("."))
            streams = {f.stem: read_parquet(f)[0] for f in stream_files}
            frame, report = differentiate(read_parquet(source)[0].to_pandas(), vehicle, params.differentiate,
                                          streams)
        except (SyncError, SchemaError) as err:
            result.quarantined.append(quarantine(err, name, shown(source, root)))
            drop_stale(target)
            drop_stale(layout.estimation_report_path(root, name))
            continue
        inputs = [source, *stream_files]
        write_parquet(to_arrow(frame), target, provenance(root, NAME, name, inputs, vehicle, params.differentiate))
        write_json({"trial": name, **report}, layout.estimation_report_path(root, name))
        result.outputs += [target, layout.estimation_report_path(root, name)]
        result.summary[name] = {"samples": len(frame), "usable_fraction": round(report["usable_fraction"], 4)}
        for found in report.get("disturbances", []):
            log.warning("differentiate %s: %s", name, found["text"])
        log.info("differentiate %s: %d samples kept (%.0f %% of the grid)", name, len(frame),
                 100 * report["usable_fraction"])
    return result


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv, extra=add_trial_argument)


if __name__ == "__main__":
    raise SystemExit(main())
