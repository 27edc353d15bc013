"""Where each stage reads and writes, relative to a run directory (the repo root under DVC).

Every stage shell takes ``--root`` (default ``.``) and uses these helpers, so that ``dvc.yaml``, the CLI
and the tests agree on paths.
"""

from __future__ import annotations

from pathlib import Path

RAW = "data/raw"
SIGNALS = "data/signals"
SYNCED = "data/synced"
KINEMATICS = "data/kinematics"
DERIVED = "data/derived"
FEATURES = "data/features"
MODELS = "data/models"
EVALUATION = "data/evaluation"
SIMULATION = "data/simulation"
REPORTS = "reports"


def signals_dir(root: Path, trial: str) -> Path:
    return Path(root) / SIGNALS / trial


def stream_path(root: Path, trial: str, stream: str) -> Path:
    return signals_dir(root, trial) / f"{stream}.parquet"


def ingest_report_path(root: Path, trial: str) -> Path:
    return signals_dir(root, trial) / "ingest_report.json"


def synced_path(root: Path, trial: str) -> Path:
    return Path(root) / SYNCED / f"{trial}.parquet"


def kinematics_path(root: Path, trial: str) -> Path:
    return Path(root) / KINEMATICS / f"{trial}.parquet"


def estimation_report_path(root: Path, trial: str) -> Path:
    """The differentiate stage's report of one trial (noise per signal, smoother or widths, usable fraction)."""
    return Path(root) / KINEMATICS / f"{trial}.estimation.json"


def derived_path(root: Path, trial: str) -> Path:
    return Path(root) / DERIVED / f"{trial}.parquet"


def features_dir(root: Path) -> Path:
    return Path(root) / FEATURES


def coverage_path(root: Path) -> Path:
    """The tune stage's extrapolation and excitation diagnostics: each test trial's inputs against the training's."""
    return Path(root) / EVALUATION / "coupled" / "coverage.json"
