"""The suite file (``redline.toml``): what to build, which tests to run, which processes to start.

    name = "objectbuilder"              # required
    tests = ["test_objectbuilder.py"]   # required: test modules, relative to this file
    build = "make"                      # optional: a shell line or an argv list (run in this dir)
    executions = 1                      # recordings per revision
    sampling_hz = 10                    # monitor samples per second
    transport = "tcp"                   # the run's zenoh network: "tcp" (a free loopback port)
                                        # or "unix" (a unix socket, unixsock-stream/PATH)

    [[component]]                       # one or more; [[fixture]] entries have the same fields
    name = "objectbuilder"
    command = ["python", "../objectbuilder.py"]   # "python" = the Python running Redline
                                        # placeholders: see below
    env = { LOG_LEVEL = "info" }
    cwd = ".."                          # default: this file's directory
    ready = { log = "ready" }           # or { delay = 1.5 }, { key = "some/zenoh/key" },
                                        # or { liveliness = "some/token/key" }
    start_timeout = 30                  # seconds to become ready
    stop_timeout = 5                    # seconds between SIGTERM and SIGKILL

Every process gets the run's zenoh configuration (peer mode, isolated) as a file whose path is
in the environment variable ``ZENOH_CONFIG`` (what ``zenoh.Config.from_env()`` reads). A program
that takes the configuration as an argument instead, as every eclipse-zenoh example does
(``--config FILE``), gets the same path through a placeholder in its ``command``:

    command = ["python", "z_sub.py", "--config", "{zenoh_config}"]

Placeholders are whole known names in single braces, substituted in ``command`` (not in ``env``,
``cwd`` or ``build``) when the process starts; the known ones:

    {zenoh_config}    the path of the run's zenoh configuration file (what ZENOH_CONFIG holds)

Any other ``{name}`` (letters, digits, '_') is an error naming the file and line; write
``{{name}}`` for a literal ``{name}``. Other braces are left as they are: JSON such as
``{"a": 1}``, and shell syntax ``${NAME}``.

Every error names the file and, where it can be found, the line.
"""

from __future__ import annotations

import hashlib
import re
import sys
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from redline.agent.affinity import Affinity, parse_affinity, parse_cores
from redline.agent.network import TRANSPORTS
from redline.agent.placeholders import PLACEHOLDERS, substitute, unknown_placeholders
from redline.recording.driver import DRIVER_PROCESS, RECORDER_PROCESS
from redline.recording.format import HOST_PROCESS, OWN_PROCESS

_TOP = {
    "name",
    "tests",
    "build",
    "executions",
    "sampling_hz",
    "transport",
    "affinity",
    "component",
    "fixture",
}
_PROCESS = {"name", "command", "env", "cwd", "ready", "start_timeout", "stop_timeout", "cpus"}
_READY = {"log", "delay", "key", "liveliness"}


#: process names Redline records its own series under: the host, its own processes, the driver
RESERVED_NAMES = frozenset({HOST_PROCESS, OWN_PROCESS, DRIVER_PROCESS, RECORDER_PROCESS})


class SuiteError(ValueError):
    """A suite file that cannot be used; the message names the file, the line and the field."""


@dataclass(frozen=True)
class ReadyCheck:
    """Readiness: a ``log`` regex, a ``delay`` in seconds, a sample on a zenoh ``key``, or a
    zenoh ``liveliness`` token matching a key expression."""

    kind: str
    value: str | float


@dataclass(frozen=True)
class ProcessSpec:
    """A component (monitored) or fixture (not monitored) process of the suite."""

    name: str
    command: tuple[str, ...]
    cwd: Path
    env: dict[str, str] = field(default_factory=dict)
    ready: ReadyCheck | None = None
    start_timeout: float = 30.0
    stop_timeout: float = 5.0
    cpus: tuple[int, ...] = ()  # the cores it may use (`redline.agent.affinity`); () all

    def expanded(self, values: Mapping[str, str]) -> ProcessSpec:
        """This process with the placeholders of its command replaced by ``values``."""
        return replace(self, command=substitute(self.command, values))


@dataclass(frozen=True)
class Suite:
    """A loaded, checked suite file. ``build`` is an argv (a shell line becomes ``sh -c LINE``)."""

    path: Path
    name: str
    tests: tuple[Path, ...]
    components: tuple[ProcessSpec, ...]
    fixtures: tuple[ProcessSpec, ...] = ()
    build: tuple[str, ...] | None = None
    executions: int = 1
    sampling_hz: float = 10.0
    transport: str = "tcp"
    sha256: str = ""
    affinity: Affinity = field(default_factory=Affinity)

    @property
    def directory(self) -> Path:
        return self.path.parent


class _Checker:
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
        pattern = re.compile(rf"^\s*{re.escape(key)}\s*=|^\s*\[\[?\s*{re.escape(key)}\s*\]")
        for number in range(start, len(self.lines)):
            in_next_table = self.lines[number].lstrip().startswith("[")
            if number > start and section is not None and in_next_table:
                break
            if pattern.match(self.lines[number]):
                return number + 1
        return None if section is None else start + 1

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
        for key in table:
            if key not in allowed:
                raise self.fail(
                    f"unknown field {key!r} in {what} (allowed: {', '.join(sorted(allowed))})",
                    key,
                    section,
                    index,
                )

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


def _string_list(
    checker: _Checker, value: Any, key: str, what: str, section: str | None = None, index: int = 0
) -> tuple[str, ...]:
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise checker.fail(
            f"{what}: {key!r} must be a non-empty list of strings, got {value!r}",
            key,
            section,
            index,
        )
    return tuple(value)


def _ready(checker: _Checker, value: Any, what: str, section: str, index: int) -> ReadyCheck:
    if not isinstance(value, dict) or len(value) != 1:
        raise checker.fail(
            f"{what}: 'ready' must be one of {{log = \"regex\"}}, "
            f'{{delay = seconds}}, {{key = "zenoh/key"}} or '
            f'{{liveliness = "zenoh/key"}}, got {value!r}',
            "ready",
            section,
            index,
        )
    checker.unknown(value, _READY, f"{what} 'ready'", section, index)
    kind, setting = next(iter(value.items()))
    if kind == "delay":
        return ReadyCheck(kind, float(checker.number(setting, "ready", what, section, index)))
    if not isinstance(setting, str) or not setting:
        raise checker.fail(
            f"{what}: ready {kind} must be a non-empty string", "ready", section, index
        )
    if kind == "log":
        try:
            re.compile(setting)
        except re.error as exc:
            raise checker.fail(
                f"{what}: ready log regex {setting!r} is invalid: {exc}", "ready", section, index
            ) from None
    return ReadyCheck(kind, setting)


def _process(checker: _Checker, table: Any, section: str, index: int) -> ProcessSpec:
    what = f"[[{section}]] #{index + 1}"
    if not isinstance(table, dict):
        raise checker.fail(f"{section!r} must be an array of tables ([[{section}]])", section)
    checker.unknown(table, _PROCESS, what, section, index)
    for required in ("name", "command"):
        if required not in table:
            raise checker.fail(
                f"{what}: missing required field {required!r}", section, section, index
            )
    name = table["name"]
    if not isinstance(name, str) or not re.match(r"^[A-Za-z0-9_.-]+$", name):
        raise checker.fail(
            f"{what}: 'name' must be letters, digits, '_', '.' or '-', got {name!r}",
            "name",
            section,
            index,
        )
    if name in RESERVED_NAMES:
        raise checker.fail(
            f"{what}: {name!r} is reserved for Redline's own series (reserved: "
            f"{', '.join(sorted(RESERVED_NAMES))})",
            "name",
            section,
            index,
        )
    command = _string_list(checker, table["command"], "command", what, section, index)
    for name in unknown_placeholders(command):
        known = ", ".join(f"{{{known}}}" for known in PLACEHOLDERS)
        raise checker.fail(
            f"{what}: unknown placeholder {{{name}}} in 'command' (known: "
            f"{known}; write {{{{{name}}}}} for a literal {{{name}}})",
            "command",
            section,
            index,
        )
    if command[0] == "python":
        command = (sys.executable, *command[1:])
    env = table.get("env", {})
    if not isinstance(env, dict) or not all(isinstance(v, str) for v in env.values()):
        raise checker.fail(f"{what}: 'env' must be a table of strings", "env", section, index)
    cwd = table.get("cwd", ".")
    if not isinstance(cwd, str):
        raise checker.fail(f"{what}: 'cwd' must be a path string", "cwd", section, index)
    ready = table.get("ready")
    try:
        cpus = parse_cores(table["cpus"], f"{what}: 'cpus'") if "cpus" in table else ()
    except ValueError as exc:
        raise checker.fail(str(exc), "cpus", section, index) from None
    return ProcessSpec(
        name=name,
        command=command,
        env=dict(env),
        cwd=(checker.path.parent / cwd).resolve(),
        ready=None if ready is None else _ready(checker, ready, what, section, index),
        start_timeout=float(
            checker.number(table.get("start_timeout", 30.0), "start_timeout", what, section, index)
        ),
        stop_timeout=float(
            checker.number(table.get("stop_timeout", 5.0), "stop_timeout", what, section, index)
        ),
        cpus=cpus,
    )


def _transport(checker: _Checker, value: Any) -> str:
    if value not in TRANSPORTS:
        raise checker.fail(
            f"'transport' must be one of {', '.join(map(repr, TRANSPORTS))}, got {value!r}",
            "transport",
        )
    return str(value)


def _parse(path: Path) -> tuple[bytes, str, dict[str, Any]]:
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


def load_suite(path: str | Path) -> Suite:
    """Load and check a suite file; raise `SuiteError` naming the file, line and field at fault."""
    path = Path(path).resolve()
    raw, text, data = _parse(path)
    checker = _Checker(path, text)
    checker.unknown(data, _TOP, "the suite")
    for required in ("name", "tests", "component"):
        if required not in data:
            raise SuiteError(f"{path}: missing required field {required!r}")
    if not isinstance(data["name"], str) or not data["name"]:
        raise checker.fail("'name' must be a non-empty string", "name")
    tests = _string_list(checker, data["tests"], "tests", "the suite")
    for test in tests:
        if not (path.parent / test).is_file():
            raise checker.fail(
                f"test module {test!r} does not exist (relative to the suite file)", "tests"
            )
    build = data.get("build")
    if isinstance(build, str):
        build = ("sh", "-c", build)
    elif build is not None:
        build = _string_list(checker, build, "build", "the suite")
    sections = {}
    for section in ("component", "fixture"):
        tables = data.get(section, [])
        if not isinstance(tables, list):
            raise checker.fail(f"{section!r} must be written as [[{section}]] tables", section)
        sections[section] = tuple(_process(checker, t, section, i) for i, t in enumerate(tables))
    if not sections["component"]:
        raise SuiteError(f"{path}: the suite names no [[component]]")
    try:
        affinity = parse_affinity(data.get("affinity"))
    except ValueError as exc:
        raise checker.fail(str(exc), "affinity") from None
    for section, specs in sections.items():  # a process without its own cores: the components'
        sections[section] = tuple(
            spec if spec.cpus else replace(spec, cpus=affinity.of("components")) for spec in specs
        )
    return Suite(
        path=path,
        name=data["name"],
        tests=tuple((path.parent / t).resolve() for t in tests),
        components=sections["component"],
        fixtures=sections["fixture"],
        build=build,
        executions=int(
            checker.number(data.get("executions", 1), "executions", "the suite", integer=True)
        ),
        sampling_hz=float(
            checker.number(data.get("sampling_hz", 10.0), "sampling_hz", "the suite")
        ),
        transport=_transport(checker, data.get("transport", "tcp")),
        sha256=hashlib.sha256(raw).hexdigest(),
        affinity=affinity,
    )
