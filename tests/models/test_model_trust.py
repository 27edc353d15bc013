"""Models load only through their card (sha256 checked before unpickling); retrain never follows inbox symlinks."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import joblib
import numpy as np
import pytest

from pipeline import registry
from pipeline.errors import ModelError
from pipeline.models.card import card_path, load_model, save_model
from pipeline.models.decoupled import LinearQuadraticDamping
from pipeline.retrain import RetrainOptions, inbox_logs, retrain
from stages import simulate as simulate_stage
from tests.cli.helpers import VEHICLE_YAML, FakeDag

REPO = Path(__file__).resolve().parents[2]


class Payload:
    """A pickle that runs code when loaded: it creates the file named in its state."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self) -> tuple[object, tuple[str, str]]:
        return (open, (self.marker, "w"))


def _damping() -> LinearQuadraticDamping:
    return LinearQuadraticDamping().fit(np.c_[[-1.0, 0.0, 1.0]], [-3.0, 0.0, 3.0])


def test_a_carded_model_round_trips(tmp_path: Path) -> None:
    path, card = save_model(_damping(), tmp_path / "u_ls.joblib", {"dof": "u"})
    est, meta = load_model(path)
    assert meta["model_file"] == "u_ls.joblib" and meta["dof"] == "u" and len(meta["model_sha256"]) == 64
    assert est.predict(np.c_[[0.5]]).shape == (1,)
    assert card == card_path(path) == tmp_path / "u_ls.card.json"


def test_a_pickle_without_a_card_is_refused_and_never_unpickled(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    joblib.dump(Payload(marker), tmp_path / "u_evil.joblib")
    with pytest.raises(ModelError, match=r"u_evil\.joblib: model has no card u_evil\.card\.json"):
        load_model(tmp_path / "u_evil.joblib")
    assert not marker.exists()


def test_a_pickle_swapped_under_its_card_is_refused_and_never_unpickled(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    path, _ = save_model(_damping(), tmp_path / "u_ls.joblib", {})
    joblib.dump(Payload(marker), path)  # replaced after the card was written
    with pytest.raises(ModelError, match=r"u_ls\.joblib: model file does not match the sha256"):
        load_model(path)
    assert not marker.exists()


@pytest.mark.parametrize("card", ["not json", json.dumps(["a list"]), json.dumps({"model_file": "u_ls.joblib"}),
                                  json.dumps({"model_file": "other.joblib", "model_sha256": "0" * 64})])
def test_a_bad_card_is_refused(tmp_path: Path, card: str) -> None:
    path, cpath = save_model(_damping(), tmp_path / "u_ls.joblib", {})
    cpath.write_text(card)
    with pytest.raises(ModelError, match=r"u_ls\.joblib: .*card"):
        load_model(path)


def test_a_card_copied_beside_another_pickle_is_refused(tmp_path: Path) -> None:
    """A valid card renamed to sit beside a dropped-in pickle with the same bytes still names its own file."""
    path, cpath = save_model(_damping(), tmp_path / "u_ls.joblib", {})
    (tmp_path / "u_x.joblib").write_bytes(path.read_bytes())
    (tmp_path / "u_x.card.json").write_text(cpath.read_text())
    with pytest.raises(ModelError, match="is the card of 'u_ls.joblib'"):
        load_model(tmp_path / "u_x.joblib")


def test_simulate_refuses_a_dropped_in_decoupled_model(tmp_path: Path) -> None:
    base = tmp_path / "data/models/decoupled"
    for dof in ("u", "v", "r"):
        save_model(_damping(), base / f"{dof}_ls.joblib", {"dof": dof, "model": "ls"})
    assert set(simulate_stage.decoupled_models(tmp_path, ["u", "v", "r"], None)) == {"ls"}
    marker = tmp_path / "pwned"
    for dof in ("u", "v", "r"):
        joblib.dump(Payload(marker), base / f"{dof}_evil.joblib")
    with pytest.raises(ModelError, match=r"[uvr]_evil\.joblib: model has no card"):
        simulate_stage.decoupled_models(tmp_path, ["u", "v", "r"], None)
    assert not marker.exists()


def test_simulate_refuses_a_coupled_model_whose_pickle_changed(tmp_path: Path) -> None:
    base = tmp_path / "data/models/coupled"
    card = {"inputs": ["u_mps", "v_mps", "r_radps", "n1_rpm"], "outputs": ["udot_mps2", "vdot_mps2", "rdot_radps2"]}
    path, _ = save_model(_damping(), base / "wdse_svr.joblib", card)
    assert set(simulate_stage.coupled_models(tmp_path, ["u", "v", "r"])) == {"coupled_wdse_svr"}
    marker = tmp_path / "pwned"
    joblib.dump(Payload(marker), path)
    with pytest.raises(ModelError, match=r"wdse_svr\.joblib: model file does not match"):
        simulate_stage.coupled_models(tmp_path, ["u", "v", "r"])
    assert not marker.exists()


def test_joblib_load_is_called_only_in_the_card_module() -> None:
    """Every model load in the project goes through pipeline.models.card.load_model."""
    callers = []
    for path in sorted([*REPO.glob("pipeline/**/*.py"), *REPO.glob("stages/**/*.py"), *REPO.glob("bench/**/*.py")]):
        text = path.read_text(encoding="utf-8")
        if re.search(r"joblib\.load\(|pickle\.loads?\(|from joblib import[^\n]*\bload\b", text):
            callers.append(str(path.relative_to(REPO)))
    assert callers == ["pipeline/models/card.py"]


# ------------------------------------------------------------------------------------ retrain: inbox symlinks

def test_inbox_symlinks_are_skipped_and_reported(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    inbox = tmp_path / "inbox"
    inbox.mkdir()
    secret = tmp_path / "secret.txt"
    secret.write_text("not a log")
    (inbox / "trial01.mcap").write_text("log")
    os.symlink(secret, inbox / "trial02.mcap")
    bag = inbox / "trial03"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("x")
    os.symlink(secret, bag / "trial03_0.db3")
    skipped: list[dict[str, str]] = []
    with caplog.at_level("WARNING", logger="pipeline.retrain"):
        logs = inbox_logs(inbox, skipped)
    assert [p.name for p in logs] == ["trial01.mcap"]
    assert [Path(e["file"]).name for e in skipped] == ["trial02.mcap", "trial03"]
    assert all("symbolic link" in e["reason"] for e in skipped)
    assert "trial02.mcap is a symbolic link" in caplog.text


def test_retrain_never_copies_a_linked_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    FakeDag(score=0.5).install(monkeypatch)
    root, inbox = tmp_path / "home", tmp_path / "inbox"
    root.mkdir()
    inbox.mkdir()
    (root / "vehicle.yaml").write_text(VEHICLE_YAML)
    for name in ("trial01", "trial02"):
        (inbox / f"{name}.mcap").write_text(f"log {name}")
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP SECRET")
    os.symlink(secret, inbox / "trial03.mcap")
    outcome = retrain(RetrainOptions(root=root, inbox=inbox, vehicle_path=root / "vehicle.yaml"))
    assert outcome.status == "promoted"
    assert [Path(q["file"]).name for q in outcome.quarantined] == ["trial03.mcap"]
    copied = [p for p in root.rglob("*") if p.is_file() and p.read_bytes() == b"TOP SECRET"]
    assert copied == []
    assert {e["name"] for e in registry.load(root)["seen_logs"].values()} == {"trial01.mcap", "trial02.mcap"}
