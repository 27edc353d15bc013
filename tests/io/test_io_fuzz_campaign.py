"""The fuzz campaign of bench/fuzz_ingest.py, a few hundred cases of it in the default test run (issue 17, item 7).

Every format's small log, mutated once per case (bit flips, byte runs, zeroed / inserted / duplicated regions,
records written twice, huge length fields, truncation, nasty CSV numbers), read in a forked child with a memory
and time limit: each case must end ok, reported (a salvage or loss the intact log does not give) or in a clean
PipelineError, never uncaught, out of memory, hung, crashed, or with messages lost or duplicated without a word.
The long mode (10,000 cases) is the bench; its table is in docs/benchmarks.md.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench" / "fuzz_ingest.py"


@pytest.fixture(scope="module")
def fuzz():
    spec = importlib.util.spec_from_file_location("fuzz_ingest", BENCH)
    module = importlib.util.module_from_spec(spec)
    sys.modules["fuzz_ingest"] = module
    spec.loader.exec_module(module)
    return module


def test_a_few_hundred_mutated_logs_of_every_format_end_clean(fuzz, capsys: pytest.CaptureFixture[str]) -> None:
    cases = 20 * len(fuzz.FORMATS)
    status = fuzz.main(["--cases", str(cases), "--seed", "7", "--timeout", "20"])
    table = capsys.readouterr().out
    assert f"{cases} cases" in table
    assert status == 0, table
    for outcome in ("uncaught", "memory", "hang", "crash", "silent-loss", "silent-dup"):
        assert f"| {outcome} |" not in table.splitlines()[2], table  # the header row names only outcomes that occurred
