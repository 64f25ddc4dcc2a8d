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
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any

from redline.agent.affinity import Affinity, parse_affinity, parse_cores
from redline.agent.network import TRANSPORTS
from redline.agent.placeholders import PLACEHOLDERS, substitute, unknown_placeholders
from redline.agent.suite_checks import Checker, SuiteError, parse_toml, string_list
from redline.recording.driver import DRIVER_PROCESS, RECORDER_PROCESS
from redline.recording.format import HOST_PROCESS, OWN_PROCESS

_TOP_REQUIRED = ("name", "tests", "component")
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


def _ready(checker: Checker, value: Any, what: str, section: str, index: int) -> ReadyCheck:
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


def _process(checker: Checker, table: Any, section: str, index: int) -> ProcessSpec:
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
    command = string_list(checker, table["command"], "command", what, section, index)
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
    if not isinstance(cwd, str) or "\0" in cwd:
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


def _transport(checker: Checker, value: Any) -> str:
    if value not in TRANSPORTS:
        raise checker.fail(
            f"'transport' must be one of {', '.join(map(repr, TRANSPORTS))}, got {value!r}",
            "transport",
        )
    return str(value)


def load_suite(path: str | Path) -> Suite:
    """Load and check a suite file; raise `SuiteError` naming the file, line and field at fault,
    one line for each problem found (each part is checked apart: a new user fixed a suite one
    error per run)."""
    path = Path(path).resolve()
    raw, text, data = parse_toml(path)
    checker, problems = Checker(path, text), []

    def checked(check: Callable[[], Any], fallback: Any = None) -> Any:
        try:
            return check()
        except SuiteError as exc:
            problems.append(str(exc))
            return fallback

    checked(lambda: checker.unknown(data, _TOP, "the suite"), None)
    problems += [f"{path}: missing required field {r!r}" for r in _TOP_REQUIRED if r not in data]
    name = data.get("name", "")
    if "name" in data and (not isinstance(name, str) or not name):
        problems.append(str(checker.fail("'name' must be a non-empty string", "name")))
    tests = checked(lambda: _tests(checker, data.get("tests")), ())
    build = checked(lambda: _build(checker, data.get("build")), None)
    sections: dict[str, tuple[ProcessSpec, ...]] = {}
    for section in ("component", "fixture"):
        tables = data.get(section, [])
        if not isinstance(tables, list):
            tables = checked(partial(_not_tables, checker, section), [])
        sections[section] = tuple(
            spec
            for i, t in enumerate(tables)
            if (spec := checked(partial(_process, checker, t, section, i)))
        )
    if data.get("component") == []:
        problems.append(f"{path}: the suite names no [[component]]")
    affinity = checked(lambda: _affinity(checker, data.get("affinity")), parse_affinity(None))
    executions = checked(
        lambda: checker.number(data.get("executions", 1), "executions", "the suite", integer=True),
        1,
    )
    sampling_hz = checked(
        lambda: checker.number(data.get("sampling_hz", 10.0), "sampling_hz", "the suite"), 10.0
    )
    transport = checked(lambda: _transport(checker, data.get("transport", "tcp")), "tcp")
    if problems:  # in the file's order, each once
        lines = dict.fromkeys(line for problem in problems for line in problem.splitlines())
        raise SuiteError("\n".join(sorted(lines, key=checker.line_in)))
    for section, specs in sections.items():  # a process without its own cores: the components'
        sections[section] = tuple(
            spec if spec.cpus else replace(spec, cpus=affinity.of("components")) for spec in specs
        )
    return Suite(
        path=path,
        name=name,
        tests=tuple((path.parent / t).resolve() for t in tests),
        components=sections["component"],
        fixtures=sections["fixture"],
        build=build,
        executions=int(executions),
        sampling_hz=float(sampling_hz),
        transport=transport,
        sha256=hashlib.sha256(raw).hexdigest(),
        affinity=affinity,
    )


def _tests(checker: Checker, value: Any) -> tuple[str, ...]:
    if value is None:
        return ()  # reported as missing
    tests = string_list(checker, value, "tests", "the suite")
    missing = [t for t in tests if not _is_file(checker.path.parent / t)]
    if missing:
        named = ", ".join(map(repr, missing))
        verb = "does not exist" if len(missing) == 1 else "do not exist"
        noun = "module" if len(missing) == 1 else "modules"
        message = f"test {noun} {named} {verb} (relative to the suite file)"
        raise checker.fail(message, "tests")
    return tests


def _is_file(path: Path) -> bool:
    """Whether ``path`` is a file; False for a name no file can have (too long, a NUL)."""
    try:
        return path.is_file()
    except (OSError, ValueError):
        return False


def _build(checker: Checker, build: Any) -> tuple[str, ...] | None:
    if isinstance(build, str):
        return ("sh", "-c", build)
    return None if build is None else string_list(checker, build, "build", "the suite")


def _not_tables(checker: Checker, section: str) -> list[Any]:
    raise checker.fail(f"{section!r} must be written as [[{section}]] tables", section)


def _affinity(checker: Checker, value: Any) -> Affinity:
    try:
        return parse_affinity(value)
    except ValueError as exc:
        raise checker.fail(str(exc), "affinity") from None
