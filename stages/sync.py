"""Sync stage: data/signals/<trial>/*.parquet -> data/synced/<trial>.parquet (one grid, validity, segments)."""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import layout
from pipeline.config import Params, Vehicle
from pipeline.errors import SchemaError, SyncError
from pipeline.sync import synchronize
from pipeline.tableio import read_parquet, remove_stale_temps, write_parquet
from stages._pertrial import add_trial_argument, drop_stale, provenance, quarantine, shown, to_arrow, trials_in
from stages.common import StageResult, stage_main

NAME = "sync"
log = logging.getLogger(__name__)


def run(root: Path, vehicle: Vehicle, params: Params, trial: str | None = None) -> StageResult:
    """Resample each trial's streams onto one uniform grid with validity masks and segment ids."""
    root = Path(root)
    result = StageResult(stage=NAME)
    remove_stale_temps(root / layout.SYNCED, targets=None if trial is None else {f"{trial}.parquet"})
    for name in trials_in(root / layout.SIGNALS, trial, dirs=True):
        source = layout.signals_dir(root, name)
        target = layout.synced_path(root, name)
        files = sorted(p for p in source.glob("*.parquet") if not p.name.startswith("."))
        try:
            if not files:
                raise SyncError("no stream files", file=shown(source, root))
            streams = {f.stem: read_parquet(f)[0] for f in files}
            frame = synchronize(streams, vehicle.for_trial(name), params.sync)
        except (SyncError, SchemaError) as err:
            result.quarantined.append(quarantine(err, name, shown(source, root)))
            drop_stale(target)
            continue
        write_parquet(to_arrow(frame), target, provenance(root, NAME, name, files, vehicle, params.sync))
        result.outputs.append(target)
        n_seg = int(frame["segment"].max()) + 1
        result.summary[name] = {"samples": len(frame), "segments": n_seg,
                                "in_segments": int((frame["segment"] >= 0).sum())}
        log.info("sync %s: %d samples, %d segment(s)", name, len(frame), n_seg)
    return result


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv, extra=add_trial_argument)


if __name__ == "__main__":
    raise SystemExit(main())
