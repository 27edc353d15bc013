"""Stage example (the repository's own run only): simulate the DAGON example trials into ``data/raw/``.

It is the first stage of ``dvc.yaml`` so that ``dvc repro`` on a fresh clone has logs to ingest; with real
trials, put the logs in ``data/raw/`` (``dvc add data/raw``) and drop this stage. The vehicle config of the
example is the packaged ``pipeline/sim/dagon.yaml``. ``python -m stages.example [--out data/raw]``.
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import sys
import tempfile
from pathlib import Path

from pipeline import layout
from pipeline.demo import DEFAULT_DURATION_S

log = logging.getLogger(__name__)


def run(out: Path, duration_s: float = DEFAULT_DURATION_S, seed: int = 0) -> list[Path]:
    """Write the example trial logs into ``out`` (replacing what is there), atomically per directory."""
    from pipeline.sim import example

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        written = example(tmp / "gen", fmt="mcap", duration_s=duration_s, seed=seed)
        target = tmp / "raw"
        target.mkdir()
        logs = []
        for path in written.trials:
            os.replace(path, target / Path(path).name)
            logs.append(target / Path(path).name)
        if out.exists():
            shutil.rmtree(out)
        os.replace(target, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return [out / p.name for p in logs]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m stages.example", description=__doc__)
    parser.add_argument("--out", type=Path, default=Path(layout.RAW), help="where the logs go (default: data/raw)")
    parser.add_argument("--duration-s", type=float, default=DEFAULT_DURATION_S)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logs = run(args.out, args.duration_s, args.seed)
    print(f"example: {len(logs)} trial log(s) in {args.out}", file=sys.stdout)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
