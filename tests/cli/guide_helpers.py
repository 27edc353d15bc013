"""The code blocks of a section of docs/user-guide.md, so that a walkthrough's test runs the guide's own text: the
guide and the test cannot drift apart."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "user-guide.md"
_FENCE = re.compile(r"^```(\w+)\n(.*?)^```", re.M | re.S)


def guide_section(title: str) -> str:
    """The text of the ``## `` section whose heading holds ``title``, up to the next ``## `` heading."""
    text = GUIDE.read_text(encoding="utf-8")
    heading = re.compile(rf"^## [^\n]*{re.escape(title)}[^\n]*$", re.M).search(text)
    assert heading is not None, f"no '## ...{title}...' heading in {GUIDE}"
    after = re.compile(r"^## ", re.M).search(text, heading.end())
    return text[heading.end():after.start() if after else len(text)]


def guide_fences(title: str) -> list[tuple[str, str]]:
    """(language, body) of every fenced block of that section, in order."""
    return [(m.group(1), m.group(2)) for m in _FENCE.finditer(guide_section(title))]


def guide_block(title: str, lang: str, first_line: str) -> str:
    """The ```lang block of that section whose first line is ``first_line`` (e.g. ``# ship.yaml``)."""
    found = [body for kind, body in guide_fences(title) if kind == lang and body.split("\n", 1)[0] == first_line]
    assert len(found) == 1, f"{len(found)} ```{lang} blocks starting {first_line!r} in the section '{title}'"
    return found[0]


def command_args(line: str, program: str = "auvid") -> list[str] | None:
    """The arguments of a ``program ...`` command line (a trailing ``# comment`` dropped); None for other lines."""
    words = shlex.split(line.removeprefix("$ "), comments=True)
    return words[1:] if words and words[0] == program else None
