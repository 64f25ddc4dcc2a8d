"""Checking a TOML file's tables (a suite file's), each problem named by file, line and field."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any


class SuiteError(ValueError):
    """A suite file that cannot be used; the message names the file, the line and the field."""


class Checker:
    """Reads fields out of the parsed TOML, turning every mistake into a SuiteError with a line."""

    def __init__(self, path: Path, text: str) -> None:
        self.path = path
        self.lines = text.splitlines()

    def line_of(self, key: str, section: str | None = None, index: int = 0) -> int | None:
        start = 0
        if section is not None:
            headers = [
                n
                for n, line in enumerate(self.lines)
                if re.match(rf"^\s*\[\[\s*{re.escape(section)}\s*\]\]", line)
            ]
            if index >= len(headers):
                return None
            start = headers[index]
        # a key of its own line, a table's header, or a key inside an inline table
        # (``ready = { logg = "..." }``: a new user's typo was named at the section's header)
        name = re.escape(key)
        pattern = re.compile(rf"^\s*{name}\s*=|^\s*\[\[?\s*{name}\s*\]|[{{,]\s*{name}\s*=")
        for number in range(start, len(self.lines)):
            in_next_table = self.lines[number].lstrip().startswith("[")
            if number > start and section is not None and in_next_table:
                break
            if pattern.search(self.lines[number]):
                return number + 1
        return None if section is None else start + 1

    def line_in(self, message: str) -> int:
        """The line a message of `fail` names (0 when it names none)."""
        found = re.match(rf"{re.escape(str(self.path))}:(\d+)", message)
        return int(found.group(1)) if found else 0

    def fail(
        self, message: str, key: str, section: str | None = None, index: int = 0
    ) -> SuiteError:
        line = self.line_of(key, section, index)
        where = f"{self.path}:{line}" if line else str(self.path)
        return SuiteError(f"{where}: {message}")

    def unknown(
        self,
        table: dict[str, Any],
        allowed: set[str],
        what: str,
        section: str | None = None,
        index: int = 0,
    ) -> None:
        unknown = [
            str(
                self.fail(
                    f"unknown field {key!r} in {what} (allowed: {listed})", key, section, index
                )
            )
            for key in table
            if key not in allowed and (listed := ", ".join(sorted(allowed)))
        ]
        if unknown:
            raise SuiteError("\n".join(unknown))

    def number(
        self,
        value: Any,
        key: str,
        what: str,
        section: str | None = None,
        index: int = 0,
        *,
        integer: bool = False,
    ) -> float:
        kinds = (int,) if integer else (int, float)
        if isinstance(value, bool) or not isinstance(value, kinds) or value <= 0:
            kind = "a positive integer" if integer else "a positive number"
            raise self.fail(f"{what}: {key!r} must be {kind}, got {value!r}", key, section, index)
        return value


def string_list(
    checker: Checker, value: Any, key: str, what: str, section: str | None = None, index: int = 0
) -> tuple[str, ...]:
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise checker.fail(
            f"{what}: {key!r} must be a non-empty list of strings, got {value!r}",
            key,
            section,
            index,
        )
    return tuple(value)


def parse_toml(path: Path) -> tuple[bytes, str, dict[str, Any]]:
    try:
        raw = path.read_bytes()
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SuiteError(f"{path}: not UTF-8 text: {exc}") from None
    except OSError as exc:
        raise SuiteError(f"{path}: cannot read the suite file: {exc.strerror or exc}") from None
    try:
        return raw, text, tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        found = re.search(r"\(at line (\d+), column (\d+)\)", str(exc))
        message = re.sub(r"\s*\(at line \d+, column \d+\)", "", str(exc))
        where = f"{path}:{found.group(1)}:{found.group(2)}" if found else str(path)
        raise SuiteError(f"{where}: malformed TOML: {message}") from None
