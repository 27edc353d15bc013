"""Where the tests find third-party fixture files.

Shipped with the tests (licence allows it): ``tests/fixtures/`` (see its README). Not shipped (licence not
stated): taken from ``../shared/fixtures`` beside the checkout; a test that needs one of those skips, naming the
file, where it is missing.
"""

from __future__ import annotations

from pathlib import Path

import pytest

SHIPPED = Path(__file__).resolve().parent / "fixtures"
SHARED = Path(__file__).resolve().parents[2] / "shared" / "fixtures"


def shared_fixture(relative: str) -> Path:
    """``../shared/fixtures/<relative>``, or a skip naming it (call inside a test or fixture)."""
    path = SHARED / relative
    if not path.exists():
        pytest.skip(f"{relative} is not shipped with the tests (licence not stated); put ../shared/fixtures "
                    "beside the checkout to run this test")
    return path


T200_CSV = "csv/bluerobotics_t200_performance_10-20V.csv"  # Blue Robotics' T200 table (not shipped)
