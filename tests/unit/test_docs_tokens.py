"""The documentation never shows a token on a command line: every user of the machine reads a
process's arguments in `ps` (docs/security.md, "Secrets"). A review found six curl examples
that sent `-H "Authorization: Bearer $TOKEN"`, while the `ci` commands had dropped `--token`
for that reason."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md")])
#: a token in an argument: a bearer header written out (``-H``, ``--header``, with or without a
#: space), a user and password (``-u``), or a token option given a value
ON_THE_COMMAND_LINE = re.compile(
    r"""(-H|--header)\s*["']?Authorization:|\s(-u|--user)\s+\S+:|--token[= ]+["$]"""
)


@pytest.mark.parametrize("page", PAGES, ids=lambda page: page.name)
def test_no_example_puts_a_token_on_the_command_line(page: Path) -> None:
    found = [
        f"{page.name}:{number}: {line.strip()}"
        for number, line in enumerate(page.read_text().splitlines(), 1)
        if ON_THE_COMMAND_LINE.search(line)
    ]
    assert not found, "\n".join(found)
