"""Features stage: data/derived/*.parquet -> the feature store data/features/vehicle=<v>/trial=<t>/part-0.parquet."""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import layout, store
from pipeline.config import Params, Vehicle
from pipeline.errors import SchemaError
from pipeline.tableio import read_parquet, remove_stale_temps
from stages._pertrial import add_trial_argument, drop_stale, provenance, quarantine, shown, trials_in
from stages.common import StageResult, stage_main

NAME = "features"
log = logging.getLogger(__name__)


def run(root: Path, vehicle: Vehicle, params: Params, trial: str | None = None) -> StageResult:
    """Label splits and write every derived table into the hive-partitioned feature store."""
    root = Path(root)
    result = StageResult(stage=NAME)
    written: list[str] = []
    remove_stale_temps(store.partition_dir(root, vehicle.name, trial) if trial else layout.features_dir(root),
                       recursive=True)
    store.check_test_trials(params.features, trials_in(root / layout.DERIVED, None), _seen_trials(root))
    for name in trials_in(root / layout.DERIVED, trial):
        source = layout.derived_path(root, name)
        target = store.partition_dir(root, vehicle.name, name) / store.PART_FILE
        try:
            if not source.exists():
                raise SchemaError("no derived table (run the derive stage)", file=shown(source, root))
            frame = read_parquet(source)[0].to_pandas()
            prov = provenance(root, NAME, name, [source], vehicle, params.features)
            result.outputs.append(store.write_trial(root, vehicle.name, name, frame, params.features, prov,
                                                      vehicle.actuator_signals()))
        except SchemaError as err:
            result.quarantined.append(quarantine(err, name, shown(source, root)))
            drop_stale(target)
            continue
        written.append(name)
        result.summary[name] = {"rows": len(frame)}
    if trial is None:  # a full run: partitions of trials that are gone (or quarantined now) are removed
        for path in store.prune(root, vehicle.name, written):
            log.info("features: removed stale partition %s", shown(path, root))
    return result


def _seen_trials(root: Path) -> set[str]:
    """Trials the run has seen before features: ingested (data/signals/) or waiting as logs (data/raw/)."""
    from pipeline.ingest import trial_id
    from stages.common import discover_trials
    from stages.ingest import discover_logs

    return set(discover_trials(root)) | {trial_id(p) for p in discover_logs(root)}


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv, extra=add_trial_argument)


if __name__ == "__main__":
    raise SystemExit(main())
