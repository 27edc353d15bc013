"""The registry document: empty default, atomic save, versions, unknown formats refused."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pipeline import registry


def test_empty_then_roundtrip(tmp_path: Path) -> None:
    data = registry.load(tmp_path)
    assert data == registry.empty() and registry.next_version(data) == "v0001"
    data["versions"].append({"version": "v0001", "status": "promoted", "holdout_score": 0.5})
    data["current"] = "v0001"
    registry.save(tmp_path, data)
    again = registry.load(tmp_path)
    assert again["current"] == "v0001" and registry.current(again)["holdout_score"] == 0.5
    assert registry.next_version(again) == "v0002"
    assert registry.current_model_dir(tmp_path) == tmp_path / "models/v0001"
    assert not list(tmp_path.glob(".registry.json.*"))  # no temp file left


def test_point_current_is_a_relative_symlink(tmp_path: Path) -> None:
    (tmp_path / "models/v0002").mkdir(parents=True)
    registry.point_current(tmp_path, "v0002")
    registry.point_current(tmp_path, "v0002")
    assert (tmp_path / "current").resolve() == (tmp_path / "models/v0002").resolve()
    assert not (tmp_path / "current").readlink().is_absolute()


@pytest.mark.parametrize("content", ["{not json", json.dumps({"format": 99}), json.dumps([1, 2])])
def test_unreadable_or_unknown_format_is_refused(tmp_path: Path, content: str) -> None:
    (tmp_path / "registry.json").write_text(content)
    with pytest.raises(registry.RegistryError):
        registry.load(tmp_path)
