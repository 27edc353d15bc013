"""The ``auvid`` command: the only place that prints, shows progress bars and chooses exit codes.

Exit codes: 0 done; 1 done, but some inputs were quarantined or some models failed (each named; see the report);
2 usage or config error (missing paths, nothing to process, a config mistake that stops every log), found before
any stage runs; 3 a stage failed (nothing half-written: every output is written atomically); 130 interrupted
(Ctrl-C); 141 output pipe closed (``auvid inspect ... | head``). Neither of the last two prints a traceback.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

from pipeline import __version__
from pipeline.cli.common import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_PIPE, EXIT_USAGE, UsageError
from pipeline.errors import ConfigError, PipelineError, RunRootBusy

# A help text naming a setting says "(default, section.key: value)" and the other values in parentheses;
# tests/cli/test_cli.py checks both against the params model (importing it here would cost every command ~0.2 s).
STAGE_HELP = {
    "ingest": "read trial logs (MCAP, ROS 1/2 bags, CSV) into per-stream Parquet at native rate",
    "sync": "put each trial's streams on one uniform grid with validity masks and segments",
    "differentiate": "velocities and accelerations: a Kalman/RTS smoother over every velocity and "
                     "rate sensor at its own stamps (default, differentiate.method: kalman), or filters of the "
                     "synced grid (gaussian, savgol)",
    "derive": "thrust per thruster, generalized forces tau, damping target d",
    "features": "write the Parquet feature store with tuning / train-test / test split labels",
    "tune": "hyperparameter search for the coupled SVRs on the rows the final model is fitted on (default, "
            "coupled.tuning: nested; the train stage searches each CV fold's own), or once on the tuning split "
            "(split)",
    "train": "fit and cross-validate the coupled models (SVR variants, Gertler-Hagen, McFarland-Whitcomb)",
    "decoupled": "fit and cross-validate the decoupled damping models (LS, MLP, KRR, SVR, GP)",
    "simulate": "free-run rollouts on the test trial, DVL-outage bridging",
    "report": "one self-contained HTML report + reports/metrics.json",
}

EPILOG = """\
examples:
  auvid demo                                   # simulated example, whole DAG, prints where the report is
  auvid inspect trial01.mcap                   # topics, types, rates, gaps, stamp warnings
  auvid init data/raw/*.mcap -o dagon.yaml     # a starter vehicle config: fill in its TODOs
  auvid run --root runs/basin --vehicle dagon.yaml data/raw/*.mcap
  auvid sync --root runs/basin --vehicle dagon.yaml --trial trial01
  auvid report --root runs/basin --vehicle dagon.yaml
  auvid retrain --root /srv/auvid --inbox /srv/incoming --vehicle dagon.yaml
  auvid models list --root /srv/auvid          # registered model versions; show, promote, rollback
  auvid export runs/basin                      # one MCAP per trial for Foxglove / PlotJuggler
  auvid predict new.mcap --root runs/basin     # the models' accelerations on a new log (or a Parquet table)
  AUVID_SCHEDULER=tcp://scheduler:8786 auvid run ...   # fan-out on a Dask cluster (or --scheduler)

exit codes: 0 done, 1 done with quarantined inputs or failed models, 2 usage or config error (before any stage
  runs), 3 a stage failed, 130 interrupted, 141 output pipe closed (e.g. `| head`).
-q: no progress, no per-stage lines, library warnings off: one summary line per run (cron).
DVC: `dvc repro` runs the same stages from dvc.yaml (pip install -e '.[dvc]'). See docs/user-guide.md.
"""


# ---------------------------------------------------------------------------------------------- arguments

def _abs_path(text: str) -> Path:
    """A path argument made absolute at once: stages may run in worker processes started from another directory
    (a process pool kept from an earlier call, a Dask worker), where a relative path means another file."""
    return Path(text).expanduser().resolve()


def _add_config(p: argparse.ArgumentParser, vehicle_required: bool = False) -> None:
    p.add_argument("--root", type=_abs_path, default=".", help="run directory holding data/ and reports/ "
                   "(default: .)")
    p.add_argument("--vehicle", type=Path, default=None,
                   help="vehicle config YAML (default: ./vehicle.yaml, else <root>/vehicle.yaml)")
    p.add_argument("--params", type=Path, default=None,
                   help="params YAML (default: <root>/params.yaml if present, else built-in defaults)")


def _add_ingest_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-checksum", dest="checksum", action="store_const", const="none", default=None,
                   help="do not compute each raw log's sha256 for the outputs' provenance (params ingest.checksum: "
                        "none for this call; provenance then says checksum none); saves reading the log once more")


def _add_definitions(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vehicle", type=Path, default=None, help="vehicle config: its message_definitions and the "
                   "CSV options of its streams are used")
    p.add_argument("--msgs", dest="definitions", action="append", type=Path, default=[], metavar="DIR",
                   help="directory of .msg/.idl files for types the log does not embed (repeatable; a ROS package "
                        "tree works)")


def _add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler (tcp://host:8786), or local[:N] for a LocalCluster of N workers, for "
                        "per-trial and CV/search fan-out (default: $AUVID_SCHEDULER, else local processes, "
                        "serial for small inputs)")
    p.add_argument("-q", "--quiet", action="store_true", help="one summary line per run: no progress bars, "
                   "no per-stage lines, no warnings")
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="auvid", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EPILOG,
        description="From underwater-vehicle trial logs to identified, validated motion models.\n\n"
                    "The DAG: ingest -> sync -> differentiate -> derive -> features -> tune -> train -> "
                    "decoupled -> simulate -> report.\nEach stage has its own subcommand; `run` does them all.")
    parser.add_argument("--version", action="version", version=f"auvid {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    demo = sub.add_parser("demo", help="simulate an example vehicle, run the whole DAG on it, print the report "
                          "path", formatter_class=argparse.RawDescriptionHelpFormatter,
                          epilog="example:\n  auvid demo --out /tmp/auvid-demo\n")
    demo.add_argument("--out", type=Path, default=Path("auvid-demo"), help="output directory (default: "
                      "./auvid-demo)")
    demo.add_argument("--duration-s", type=float, default=None, help="length of each simulated trial")
    _add_run_options(demo)

    run = sub.add_parser("run", help="run every stage in DAG order (without DVC)",
                         formatter_class=argparse.RawDescriptionHelpFormatter,
                         epilog="examples:\n  auvid run --root runs/basin --vehicle dagon.yaml data/raw/*.mcap\n"
                                "  auvid run --root runs/basin --vehicle dagon.yaml --from features\n")
    _add_config(run)
    run.add_argument("logs", nargs="*", type=_abs_path, help="logs to ingest (default: everything under data/raw/)")
    _add_ingest_options(run)
    run.add_argument("--from", dest="first", choices=_stage_names(), help="start at this stage")
    run.add_argument("--to", dest="last", choices=_stage_names(), help="stop after this stage")
    _add_run_options(run)

    for name in _stage_names():
        p = sub.add_parser(name, help=STAGE_HELP[name], description=STAGE_HELP[name],
                           formatter_class=argparse.RawDescriptionHelpFormatter,
                           epilog=f"example:\n  auvid {name} --root runs/basin --vehicle dagon.yaml"
                                  + (" data/raw/trial01.mcap" if name == "ingest" else "")
                                  + (" --trial trial01" if name in ("sync", "differentiate", "derive") else "")
                                  + "\n")
        _add_config(p)
        if name == "ingest":
            p.add_argument("logs", nargs="*", type=_abs_path, help="logs to ingest (default: everything under "
                           "data/raw/)")
            _add_ingest_options(p)
        if name in ("sync", "differentiate", "derive"):
            p.add_argument("--trial", default=None, help="one trial (default: every trial with input)")
        _add_run_options(p)

    insp = sub.add_parser("inspect", help="list a log's topics (or text files' columns), types, serialization, "
                          "rates, gaps and time-stamp warnings", formatter_class=argparse.RawDescriptionHelpFormatter,
                          epilog="examples:\n  auvid inspect trial01.mcap\n  auvid inspect rosbag2_dir/ --json\n"
                                 "  auvid inspect run07.dat                     # one text file: sniffed options\n"
                                 "  auvid inspect csv_trial/ --vehicle ship.yaml  # the config's CSV options\n"
                                 "  auvid inspect bag/ --msgs ~/ws/src --fields /mavros/rc/override\n"
                                 "Use its output to write the `streams:` of a vehicle config, or let `auvid init` "
                                 "write a starter (docs/user-guide.md).\n")
    insp.add_argument("log", type=Path, help="an MCAP file, ROS 1 bag, ROS 2 bag (directory or storage file), a "
                      "text file or a directory of them")
    _add_definitions(insp)
    insp.add_argument("--fields", metavar="TOPIC", default=None, help="list the field paths of TOPIC's type "
                      "(a text file: its columns), for `signals:` in the vehicle config")
    insp.add_argument("--json", action="store_true", help="machine-readable output")
    insp.add_argument("-v", "--verbose", action="store_true", help="debug logging")

    init = sub.add_parser("init", help="write a starter vehicle config from logs (topics recognised, clocks "
                          "chosen, TODO markers for the physical constants)",
                          formatter_class=argparse.RawDescriptionHelpFormatter,
                          epilog="examples:\n  auvid init data/raw/trial01.mcap data/raw/trial02.mcap -o vehicle.yaml\n"
                                 "  auvid init bag/ --msgs ~/ws/src --name bluerov2 -o bluerov2.yaml\n"
                                 "Then fill in every TODO; `auvid ingest` (or any stage) lists those left.\n")
    init.add_argument("logs", nargs="+", type=Path, help="one or more logs of the vehicle")
    init.add_argument("-o", "--out", type=Path, default=Path("vehicle.yaml"), help="where to write the config "
                      "(default: ./vehicle.yaml; '-' prints it)")
    init.add_argument("--name", default=None, help="vehicle name (default: from the first log's name)")
    init.add_argument("--msgs", dest="definitions", action="append", type=Path, default=[], metavar="DIR",
                      help="directory of .msg/.idl files for types the logs do not embed (repeatable); written "
                           "to the config as message_definitions")
    init.add_argument("--force", action="store_true", help="overwrite an existing output file")
    init.add_argument("-v", "--verbose", action="store_true", help="debug logging")

    rt = sub.add_parser("retrain", help="ingest new logs from an inbox, retrain, promote only if better "
                        "(cron-safe)", formatter_class=argparse.RawDescriptionHelpFormatter,
                        epilog="example (cron, every night at 02:30):\n"
                               "  30 2 * * * auvid retrain --root /srv/auvid --inbox /srv/incoming "
                               "--vehicle /srv/auvid/dagon.yaml -q\n"
                               "A second run while one holds the lock exits 0 with a message. "
                               "See docs/retraining.md.\n")
    rt.add_argument("--root", type=Path, required=True, help="retraining home: registry.json, store, models")
    rt.add_argument("--inbox", type=Path, required=True, help="directory where new trial logs arrive")
    rt.add_argument("--vehicle", type=Path, default=None,
                    help="vehicle config (default: <root>/vehicle.yaml)")
    rt.add_argument("--params", type=Path, default=None, help="params YAML (default: <root>/params.yaml)")
    _add_run_options(rt)

    ex = sub.add_parser("export", help="one MCAP per trial (JSON channels) for Foxglove and PlotJuggler: synced "
                        "signals, estimated velocities with bands, model predictions, free runs",
                        formatter_class=argparse.RawDescriptionHelpFormatter,
                        epilog="examples:\n  auvid export runs/basin                      # every trial -> "
                               "runs/basin/exports/<trial>.mcap\n"
                               "  auvid export runs/basin --trial trial03 --out /tmp/mcap\n"
                               "  auvid export runs/basin --fossen ls          # Fossen YAML + UUV Simulator\n"
                               "Channels: docs/user-guide.md, 'Looking at a run in Foxglove or PlotJuggler'.\n")
    ex.add_argument("root", type=_abs_path, help="run directory (holding data/synced, data/kinematics, ...)")
    ex.add_argument("--trial", action="append", default=None, metavar="T",
                    help="export this trial only (repeatable; default: every trial with a synced table)")
    ex.add_argument("--out", type=_abs_path, default=None, help="output directory (default: ROOT/exports)")
    ex.add_argument("--params", type=Path, default=None, help="the run's params YAML, whose coupled.models and "
                    "decoupled.models are the models exported (default: ROOT/params.yaml if present)")
    ex.add_argument("--fossen", default=None, metavar="MODEL", help="instead of MCAP: the physics model MODEL (a "
                    "decoupled ls) as a Fossen YAML and UUV Simulator parameters (OUT/fossen_MODEL.yaml, "
                    "OUT/uuv_MODEL.xml), each coefficient with its 95%% interval and trials")
    ex.add_argument("-q", "--quiet", action="store_true", help="one summary line; no progress, no warnings")
    ex.add_argument("-v", "--verbose", action="store_true", help="debug logging")

    pr = sub.add_parser("predict", help="the fitted models' accelerations (with a band where a model has one) on a "
                        "new log or a Parquet table", formatter_class=argparse.RawDescriptionHelpFormatter,
                        epilog="examples:\n  auvid predict trial09.mcap --root runs/basin -o trial09.parquet\n"
                               "  auvid predict table.parquet --root /srv/auvid --alias champion -o pred.csv\n"
                               "A log runs through ingest..derive with the run's vehicle.yaml and params.yaml in a "
                               "temporary directory. Columns: docs/user-guide.md, 'Use the model'.\n")
    pr.add_argument("input", type=_abs_path, help="a log (any format ingest reads) or a .parquet table with the "
                    "models' input columns")
    pr.add_argument("--root", type=_abs_path, default=Path("."), help="run directory, retraining home or "
                    "HOME/models/<version> (default: .)")
    pr.add_argument("--version", default=None, help="a registered version (default: the registry's current)")
    pr.add_argument("--alias", default=None, help="the per-output models an alias names, e.g. champion")
    pr.add_argument("--model", action="append", default=None, metavar="NAME", help="only this model (repeatable; "
                    "default: every model the run's params name)")
    pr.add_argument("-o", "--out", type=_abs_path, default=None, help="output .parquet or .csv (default: "
                    "./<input>.predictions.parquet)")
    pr.add_argument("--vehicle", type=Path, default=None, help="vehicle config (default: the run's vehicle.yaml)")
    pr.add_argument("--params", type=Path, default=None, help="params YAML (default: the run's params.yaml)")
    pr.add_argument("-q", "--quiet", action="store_true", help="one summary line; no progress, no warnings")
    pr.add_argument("-v", "--verbose", action="store_true", help="debug logging")

    models = sub.add_parser("models", help="the retraining registry: list versions, show one, promote, roll back",
                            formatter_class=argparse.RawDescriptionHelpFormatter,
                            epilog="examples:\n  auvid models list --root /srv/auvid\n"
                                   "  auvid models show v0004 --root /srv/auvid\n"
                                   "  auvid models promote v0004 --root /srv/auvid\n"
                                   "  auvid models rollback --root /srv/auvid\n"
                                   "promote and rollback take the retrain lock. See docs/retraining.md.\n")
    msub = models.add_subparsers(dest="models_command", metavar="ACTION", required=True)
    actions = {"list": "every version: status, created_at, holdout score, parent, reason (* = current)",
               "show": "one version: lineage, metrics, why it was promoted or rejected, manual events",
               "promote": "make a registered version the current model, or (--model) one of its models the "
                          "champion for some outputs",
               "rollback": "make the current model's parent current again"}
    for action, text in actions.items():
        a = msub.add_parser(action, help=text, description=text)
        if action in ("show", "promote"):
            a.add_argument("version", help="a registered version, e.g. v0004")
        if action == "promote":
            a.add_argument("--model", default=None, metavar="NAME", help="promote this model of the version only "
                           "(e.g. ls, coupled_wdse_svr) under --alias, leaving the current version as it is")
            a.add_argument("--output", action="append", default=None, metavar="COLUMN", help="with --model: only "
                           "for this output (repeatable, e.g. udot_mps2; default: every output the model has)")
            a.add_argument("--alias", default="champion", help="with --model: the alias to point (default: "
                           "champion)")
        a.add_argument("--root", type=Path, default=Path("."), help="retraining home holding registry.json "
                       "(default: .)")
        if action in ("list", "show"):
            a.add_argument("--json", action="store_true", help="machine-readable output")
        a.add_argument("-q", "--quiet", action="store_true", help="no warnings (the output is unchanged)")
        a.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return parser


def _stage_names() -> list[str]:
    return list(STAGE_HELP)


def _dispatch(args: argparse.Namespace) -> int:
    """Run the command: each command group's module is imported only when it runs. Commands that fan out no joblib
    work run without a backend: no joblib import, and no Dask client connected because AUVID_SCHEDULER happens to
    be set."""
    if args.command == "inspect":
        from pipeline.cli.inspect import cmd_inspect

        return cmd_inspect(args)
    if args.command == "init":
        from pipeline.cli.init import cmd_init

        return cmd_init(args)
    if args.command == "models":
        from pipeline.cli.models import cmd_models

        return cmd_models(args)
    if args.command == "export":
        from pipeline.cli.export import cmd_export

        return cmd_export(args)
    if args.command == "predict":
        from pipeline.cli.predict import cmd_predict

        return cmd_predict(args)
    from pipeline.parallel import backend

    with backend(getattr(args, "scheduler", None)):
        if args.command == "retrain":
            from pipeline.cli.retrain import cmd_retrain

            return cmd_retrain(args)
        from pipeline.cli.run import cmd_demo, cmd_run, cmd_stages

        if args.command == "demo":
            return cmd_demo(args)
        if args.command == "run":
            return cmd_run(args)
        return cmd_stages(args, [args.command])


def _stdout_to_devnull() -> None:
    """After a broken pipe: the interpreter's final flush of stdout must not raise again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # stdout replaced by something without a descriptor
        pass


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "verbose", False):
        level = logging.DEBUG
    else:
        level = logging.ERROR if getattr(args, "quiet", False) else logging.WARNING
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    try:
        code = _dispatch(args)
        sys.stdout.flush()  # a closed pipe shows here, inside the handler, not at interpreter exit
        return code
    except BrokenPipeError:
        _stdout_to_devnull()
        return EXIT_PIPE
    except UsageError as err:
        print(f"auvid: usage error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except ConfigError as err:
        print(f"auvid: config error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except RunRootBusy as err:  # another command is writing the run directory: nothing done
        print(f"auvid: {args.command}: {err}", file=sys.stderr)
        return EXIT_USAGE
    except PipelineError as err:
        print(f"auvid: {args.command} failed: {err}", file=sys.stderr)
        return EXIT_FAILED
    except FileNotFoundError as err:
        print(f"auvid: {err}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as err:  # a full disk, a read-only or vanished directory: the outputs written so far are whole
        where = f" ({err.filename})" if err.filename else ""
        print(f"auvid: {args.command} failed: {err.strerror or err}{where}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print("auvid: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

