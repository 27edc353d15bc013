"""``python -m stages``: list the DAG's stages; ``python -m stages NAME ARGS...`` runs one (as ``python -m
stages.NAME ARGS...`` does)."""

from __future__ import annotations

import sys

from stages.common import EXIT_USAGE, STAGE_ORDER, MissingStageError, load_stage


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: python -m stages NAME [ARGS...]   (or: python -m stages.NAME --help)")
        print("stages, in DAG order: " + " -> ".join(STAGE_ORDER))
        return 0 if argv else EXIT_USAGE
    try:
        module = load_stage(argv[0])
    except MissingStageError as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_USAGE
    return int(module.main(argv[1:]))


if __name__ == "__main__":
    raise SystemExit(main())
