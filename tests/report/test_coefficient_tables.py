"""The report's table of a physics model's identified coefficients with their intervals, read from its card."""

from __future__ import annotations

import json
import re
from pathlib import Path

from pipeline import layout
from pipeline.report.studies import coefficient_tables, label


def _card(root: Path, model: str, intervals: dict | None) -> None:
    folder = root / layout.MODELS / "coupled"
    folder.mkdir(parents=True, exist_ok=True)
    card = {"model": model, "coefficients": {"X_udot": -21.5, "X_u": -9.8, "Y_v": 0.0}}
    if intervals is not None:
        card["coefficient_intervals"] = {"level": 0.9, "block_rows": 82, "blocks": 37, "replicates": 200,
                                         "failed_replicates": 0, "intervals": intervals,
                                         "blocks_too_short": model == "graybox_fossen"}
    (folder / f"{model}.card.json").write_text(json.dumps(card))


def test_each_selected_coefficient_is_shown_with_its_interval_once(tmp_path: Path) -> None:
    ci = {"X_u": [-11.0, -8.5], "X_udot": [-23.0, -20.0]}  # as a card stores them (sorted); Y_v not selected
    _card(tmp_path, "fossen", ci)
    _card(tmp_path, "graybox_fossen", ci)  # the same base: not shown twice
    _card(tmp_path, "rbf_svr", None)
    used: set[str] = set()
    html = coefficient_tables(tmp_path, used)
    assert html.count("<table>") == 1 and label("fossen") in html and "90% intervals" in html
    assert "37 blocks of 82 rows" in html and "200 replicates" in html and "too narrow" not in html
    rows = [re.findall(r"<td[^>]*>(.*?)</td>", r, flags=re.S) for r in re.findall(r"<tr>(.*?)</tr>", html, re.S)[1:]]
    assert [r[0] for r in rows] == ["X_udot", "X_u"]
    assert rows == [["X_udot", "-21.5", "-23", "-20"], ["X_u", "-9.8", "-11", "-8.5"]]
    assert f"{layout.MODELS}/coupled/fossen.card.json" in used


def test_blocks_shorter_than_the_errors_correlation_asks_for_are_said_to_give_narrow_intervals(tmp_path: Path) -> None:
    _card(tmp_path, "graybox_fossen", {"X_u": [-11.0, -8.5]})
    _card(tmp_path, "fossen", {"X_u": [-11.0, -8.5]})
    assert "too narrow" not in coefficient_tables(tmp_path, set())
    card = json.loads((tmp_path / layout.MODELS / "coupled" / "fossen.card.json").read_text())
    card["coefficient_intervals"]["blocks_too_short"] = True
    (tmp_path / layout.MODELS / "coupled" / "fossen.card.json").write_text(json.dumps(card))
    assert "likely too narrow" in coefficient_tables(tmp_path, set())


def test_no_table_without_intervals(tmp_path: Path) -> None:
    _card(tmp_path, "fossen", None)
    assert coefficient_tables(tmp_path, set()) == ""
