"""Where a command finds its API token: a file only its owner may read, or ``REDLINE_TOKEN``;
never the command line, which every user of the machine sees in ``ps`` (`redline ci report`
and `ci wait` took ``--token`` until a probe found one there)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

TokenFile = Annotated[
    Path | None,
    typer.Option(
        help="a file holding the token, readable by you only (chmod 600); else REDLINE_TOKEN",
        dir_okay=False,
    ),
]


def read_token(token_file: Path | None, *, required: bool = True) -> str:
    """The token: from ``token_file`` (which only its owner may read) or ``REDLINE_TOKEN``; a
    clear error naming both when ``required`` and neither gives one ("" otherwise)."""
    if token_file is not None:
        try:
            mode = token_file.stat().st_mode
            token = token_file.read_text().strip()
        except OSError as exc:
            raise typer.BadParameter(
                f"cannot read {token_file}: {exc.strerror}", param_hint="--token-file"
            ) from None
        if mode & 0o077:
            raise typer.BadParameter(
                f"{token_file} is readable by other users (mode {mode & 0o777:o}); "
                f"chmod 600 {token_file}",
                param_hint="--token-file",
            )
        if not token:
            raise typer.BadParameter(f"{token_file} is empty", param_hint="--token-file")
        if (why := _malformed(token)) is not None:
            raise typer.BadParameter(f"{token_file} {why}", param_hint="--token-file")
        return token
    token = os.environ.get("REDLINE_TOKEN", "").strip()
    if not token and required:
        raise typer.BadParameter(
            "give the token in REDLINE_TOKEN or a file (--token-file FILE, mode 600)",
            param_hint="--token-file",
        )
    if token and (why := _malformed(token)) is not None:
        raise typer.BadParameter(why, param_hint="REDLINE_TOKEN")
    return token


def _malformed(token: str) -> str | None:
    """Why ``token`` cannot be a token, never quoting it; None when it can. A trial's token file
    held a comment line above the token: the request's header refused the line break, and the
    error printed both lines, the token with them, blaming the server."""
    if "\n" in token or "\r" in token:
        lines = len(token.splitlines())
        return f"holds {lines} lines: a token is one line, with nothing else in the file"
    if any(not 0x21 <= ord(char) <= 0x7E for char in token):
        return "holds a space, a control or a non-ASCII character: a token is one word"
    return None
