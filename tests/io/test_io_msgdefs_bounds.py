"""User message definitions that are not UTF-8, and directories that are no definition tree (issue 36, item 3)."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.errors import ConfigError
from pipeline.io import msgdefs
from pipeline.io.msgdefs import load_user_types


def test_a_latin1_msg_makes_only_its_type_undecodable_naming_file_and_line(tmp_path: Path) -> None:
    msg = tmp_path / "my_pkg" / "msg"
    msg.mkdir(parents=True)
    (msg / "Bad.msg").write_bytes("# Geschwindigkeit in m/s (gemessen \xfcber Grund)\nfloat64 u\n".encode("latin-1"))
    (msg / "Good.msg").write_text("float64 v\n", encoding="utf-8")
    types = load_user_types([tmp_path])
    assert "my_pkg/msg/Good" in types.types and "my_pkg/msg/Bad" not in types.types
    why = types.missing("my_pkg/msg/Bad")
    assert "Bad.msg" in why and "not UTF-8" in why and "0xfc at line 1" in why


@pytest.mark.parametrize("directory", ["/", "/proc", "/sys/kernel"])
def test_the_root_and_pseudo_file_systems_are_refused(directory: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_user_types([directory])
    assert info.value.field == "message_definitions" and repr(directory) in str(info.value)


def test_a_tree_too_large_to_be_message_packages_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(msgdefs, "MAX_ENTRIES", 50)
    for i in range(60):
        (tmp_path / f"f{i}.txt").write_text("")
    with pytest.raises(ConfigError, match="more than 50 entries"):
        load_user_types([tmp_path])
