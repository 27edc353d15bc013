"""The user guide's AUV walkthrough, run as written (issue 14: the guide walks an AUV through, tested).

Two short dives of the example DAGON-like vehicle are simulated into `logs/trial01.mcap`, `logs/trial02.mcap` (the
paths the guide uses); then the section's blocks are taken in order from docs/user-guide.md: each `auvid` line of
a ```bash block runs through the CLI entry point (exit 0); each `$ auvid ...` of a ```console block runs and must
print what the guide shows (a line cut with `...` as a prefix; exit 2 where it shows a config error); the
```yaml block `# dagon.yaml, the TODOs filled in` replaces the TODOs of the config `auvid init` wrote, and must
fill every one of them while changing nothing else `init` wrote (clock offsets aside); `# params.yaml` is
written as it stands. The model stages (`--from tune`, minutes long) are only parsed. The features the run
writes are checked to be there for both dives, the second held out.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from pipeline import cli, store
from pipeline.cli import common as cli_common
from pipeline.config import todo_markers
from pipeline.sim import generate_trial, load_example_vehicle, write_trial
from tests.cli.guide_helpers import command_args, guide_fences

TITLE = "Walkthrough: an AUV"
FILLED = "# dagon.yaml, the TODOs filled in"
DIVES = {"trial01": 3, "trial02": 4}  # name -> simulation seed
DURATION_S = 20.0


def fill_todos(written: Any, filled: Any, key: str = "") -> Any:
    """``written`` (what `auvid init` wrote) with the guide's ``filled`` values at its TODOs; a value the guide
    gives at a key that is no TODO must be what `init` wrote (a stream's ``offset_s`` aside)."""
    if isinstance(written, str) and todo_markers(written):
        return filled
    if isinstance(written, dict) and isinstance(filled, dict):
        unknown = sorted(set(filled) - set(written))
        assert not unknown, f"the guide fills keys that `auvid init` does not write: {key} {unknown}"
        return {k: fill_todos(v, filled[k], f"{key}.{k}".lstrip(".")) if k in filled else v
                for k, v in written.items()}
    if isinstance(written, list) and isinstance(filled, list) and len(written) == len(filled):
        pairs = enumerate(zip(written, filled, strict=True))
        return [fill_todos(w, f, f"{key}.{i}".lstrip(".")) for i, (w, f) in pairs]
    if key.endswith("offset_s"):
        return filled
    assert filled == written, f"{key}: the guide has {filled!r}, `auvid init` wrote {written!r}"
    return written


def run_console(block: str, capsys: pytest.CaptureFixture[str]) -> None:
    """Each `$ auvid ...` of a console block runs and prints the lines shown under it."""
    commands: list[tuple[list[str], list[str]]] = []
    for line in block.splitlines():
        args = command_args(line) if line.startswith("$ ") else None
        if args is not None:
            commands.append((args, []))
        elif commands:
            commands[-1][1].append(line)
    assert commands, block
    for args, shown in commands:
        capsys.readouterr()
        rc = cli.main(args)
        captured = capsys.readouterr()
        printed = (captured.out + captured.err).splitlines()
        expected_rc = (cli_common.EXIT_USAGE if shown and shown[0].startswith("auvid: config error")
                       else cli_common.EXIT_OK)
        assert rc == expected_rc, (args, rc, captured.err[-2000:])
        if not any("..." in s for s in shown):
            assert printed == shown, args
        for s in shown:
            prefix = s.split(" ...")[0]
            assert any(p.startswith(prefix) for p in printed), (args, prefix, printed[:5])


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_the_auv_walkthrough_runs_as_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    example = load_example_vehicle()
    for name, seed in DIVES.items():
        write_trial(generate_trial(example, duration_s=DURATION_S, seed=seed, warmup_s=2.0), "mcap",
                    tmp_path / "logs" / f"{name}.mcap")
    fences = guide_fences(TITLE)
    assert [lang for lang, _ in fences].count("yaml") == 2, fences
    ran, parsed_only, filled = [], [], False
    for lang, body in fences:
        if lang == "bash":
            for line in body.splitlines():
                args = command_args(line)
                if args is None:
                    continue
                if "--from" in args and args[args.index("--from") + 1] != "ingest":
                    cli.build_parser().parse_args(args)  # the model stages: minutes; parsed only
                    parsed_only.append(args)
                    continue
                assert cli.main(args) == cli_common.EXIT_OK, (args, capsys.readouterr().err[-2000:])
                ran.append(args)
        elif lang == "console":
            run_console(body, capsys)
            ran.append(body.splitlines()[0])
        elif lang == "yaml" and body.startswith(FILLED):
            written = yaml.safe_load(Path("dagon.yaml").read_text(encoding="utf-8"))
            assert todo_markers(written), "the guide fills a config that has no TODOs"
            doc = fill_todos(written, yaml.safe_load(body))
            assert todo_markers(doc) == []
            Path("dagon.yaml").write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
            filled = True
        elif lang == "yaml" and body.startswith("# params.yaml"):
            Path("params.yaml").write_text(body, encoding="utf-8")
        else:
            pytest.fail(f"a ```{lang} block the test does not know: {body[:80]!r}")
    assert filled and parsed_only and any(isinstance(a, list) and a[0] == "run" for a in ran), (ran, parsed_only)

    rows = store.load(tmp_path / "runs" / "dagon")
    assert set(rows["trial"]) == set(DIVES)
    assert set(rows.loc[rows["trial"] == "trial02", "split"]) == {"test"}
    assert {"n1_rpm", "tau_u_N", "udot_mps2"} <= set(rows.columns)
