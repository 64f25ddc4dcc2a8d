"""The suite file: loading the objectbuilder suite, and errors that name file, line and field."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from redline.agent.suite import SuiteError, load_suite

from tests.support import ROOT

OBJECTBUILDER = ROOT / "examples" / "objectbuilder" / "perf" / "redline.toml"

VALID = """\
name = "demo"
tests = ["test_demo.py"]

[[component]]
name = "demo"
command = ["python", "demo.py"]
ready = { log = "ready" }
"""


def write(tmp_path: Path, text: str) -> Path:
    (tmp_path / "test_demo.py").write_text("")
    path = tmp_path / "redline.toml"
    path.write_text(text)
    return path


def error_of(tmp_path: Path, text: str) -> str:
    with pytest.raises(SuiteError) as caught:
        load_suite(write(tmp_path, text))
    return str(caught.value)


def test_objectbuilder_suite_loads_with_paths_relative_to_the_file() -> None:
    suite = load_suite(OBJECTBUILDER)
    assert suite.name == "objectbuilder" and suite.executions == 1 and suite.sampling_hz == 10
    assert suite.tests == (OBJECTBUILDER.parent / "test_objectbuilder.py",)
    (component,) = suite.components
    assert component.command[0] == sys.executable  # "python" means the Python running Redline
    assert component.cwd == OBJECTBUILDER.parent
    assert component.ready is not None and component.ready.kind == "log"
    assert len(suite.sha256) == 64 and suite.build is not None and suite.build[:2] == ("sh", "-c")


def test_defaults_and_build_line(tmp_path: Path) -> None:
    suite = load_suite(write(tmp_path, 'build = "make -j2"\n' + VALID))
    assert suite.build == ("sh", "-c", "make -j2")
    assert suite.executions == 1 and suite.sampling_hz == 10.0 and suite.fixtures == ()
    component = suite.components[0]
    assert component.start_timeout == 30.0 and component.stop_timeout == 5.0


def test_malformed_toml_names_file_and_line(tmp_path: Path) -> None:
    text = VALID.replace('command = ["python", "demo.py"]', 'command = ["python", "demo.py"')
    message = error_of(tmp_path, text)
    assert message.startswith(f"{tmp_path / 'redline.toml'}:7")
    assert "malformed TOML" in message


def test_unknown_top_level_field_is_named_with_its_line(tmp_path: Path) -> None:
    message = error_of(tmp_path, VALID.replace("tests = ", "executons = 2\ntests = "))
    assert f"{tmp_path / 'redline.toml'}:2:" in message
    assert "unknown field 'executons'" in message


def test_unknown_component_field_is_named_with_its_line(tmp_path: Path) -> None:
    message = error_of(tmp_path, VALID + "stop_timout = 3\n")
    assert ":8:" in message and "unknown field 'stop_timout' in [[component]] #1" in message


def test_an_unknown_field_of_an_inline_table_is_named_with_its_line(tmp_path: Path) -> None:
    """A new user's `ready = { logg = ... }` was named at the [[component]] header, line 4."""
    message = error_of(tmp_path, VALID.replace('{ log = "ready" }', '{ logg = "ready" }'))
    assert ":7: unknown field 'logg' in [[component]] #1 'ready'" in message, message


def test_missing_required_fields_are_named(tmp_path: Path) -> None:
    assert "missing required field 'tests'" in error_of(
        tmp_path, VALID.replace('tests = ["test_demo.py"]\n', "")
    )
    message = error_of(tmp_path, VALID.replace('command = ["python", "demo.py"]\n', ""))
    assert ":4:" in message and "missing required field 'command'" in message
    assert "no [[component]]" in error_of(
        tmp_path, 'name = "x"\ntests = ["test_demo.py"]\ncomponent = []\n'
    )


def test_bad_values_are_named(tmp_path: Path) -> None:
    assert "'ready' must be one of" in error_of(
        tmp_path, VALID.replace('{ log = "ready" }', '{ log = "a", delay = 1 }')
    )
    assert "ready log regex '(' is invalid" in error_of(
        tmp_path, VALID.replace('{ log = "ready" }', '{ log = "(" }')
    )
    assert "'executions' must be a positive integer" in error_of(
        tmp_path, "executions = 0\n" + VALID
    )
    assert "'command' must be a non-empty list" in error_of(
        tmp_path, VALID.replace('["python", "demo.py"]', '"python demo.py"')
    )


def test_missing_test_module_is_named(tmp_path: Path) -> None:
    message = error_of(tmp_path, VALID.replace("test_demo.py", "test_gone.py"))
    assert ":2:" in message and "test module 'test_gone.py' does not exist" in message


def test_every_problem_of_a_suite_is_named_at_once(tmp_path: Path) -> None:
    """A new user fixed a suite one error per run: each part is checked apart, and each
    problem gets its own line with the file and line number."""
    text = (
        'name = "demo"\nexecutons = 2\nsampling_hz = -1\ntests = ["test_demo.py", "test_a.py",'
        ' "test_b.py"]\n\n[[component]]\nname = "demo"\ncommand = ["python", "demo.py"]\n'
        'start_timout = 3\nstop_timeout = 0\n\n[[fixture]]\nname = "host"\n'
        'command = ["x"]\n'
    )
    lines = error_of(tmp_path, text).splitlines()
    suite = tmp_path / "redline.toml"
    assert lines == [
        f"{suite}:2: unknown field 'executons' in the suite (allowed: affinity, build, component,"
        " executions, fixture, name, sampling_hz, tests, transport)",
        f"{suite}:3: the suite: 'sampling_hz' must be a positive number, got -1",
        f"{suite}:4: test modules 'test_a.py', 'test_b.py' do not exist (relative to the suite"
        " file)",
        f"{suite}:9: unknown field 'start_timout' in [[component]] #1 (allowed: command, cpus,"
        " cwd, env, name, ready, start_timeout, stop_timeout)",
        f"{suite}:13: [[fixture]] #1: 'host' is reserved for Redline's own series (reserved:"
        " driver, host, recorder, redline)",
    ]


@pytest.mark.parametrize(
    ("text", "expected"),
    [  # each once, as a SuiteError naming the file (a reviewer's OSError, ValueError, repeats)
        (VALID.replace("test_demo.py", "t" * 300), ["test module 'ttt"]),
        (VALID + 'cwd = "a\\u0000b"\n', ["'cwd' must be a path string"]),
        (
            'name = "x"\ntests = ["test_demo.py"]\ncomponent = [1, 2, "s"]\n',
            ["'component' must be an array of tables"],
        ),
        ('name = "x"\ntests = ["test_demo.py"]\n[component]\n', ["written as [[component]]"]),
    ],
)
def test_a_hostile_suite_gets_each_problem_once(tmp_path: Path, text: str, expected: list[str]):
    lines = error_of(tmp_path, text).splitlines()
    assert len(lines) == len(expected) and str(tmp_path) in lines[0], lines
    for line, part in zip(lines, expected, strict=True):
        assert part in line, lines


def test_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(SuiteError, match="cannot read the suite file"):
        load_suite(tmp_path / "nothing.toml")


def test_a_component_named_host_is_refused(tmp_path: Path) -> None:
    message = error_of(tmp_path, VALID.replace('name = "demo"\ncommand', 'name = "host"\ncommand'))
    assert ":5:" in message and "'host' is reserved" in message


def test_objectbuilder_full_suite_has_the_three_sweeps_and_thread_configurations() -> None:
    from redline.agent.loader import load_test_cases
    from redline.testing import validate_cases

    suite = load_suite(OBJECTBUILDER.parent / "full.toml")
    assert [c.name for c in suite.components] == [
        "objectbuilder-t1",
        "objectbuilder-t2",
        "objectbuilder-t4",
    ]
    cases = load_test_cases(suite.tests)
    validate_cases(cases)
    assert [c.name for c in cases] == ["leg_count", "leg_rate", "pose_rate", "threads"]
    assert [s["threads"] for s in cases[-1].parameter_sets()] == [1, 2, 4]


def test_sibling_modules_come_from_each_revisions_own_folder(tmp_path: Path) -> None:
    from redline.agent.loader import load_test_cases

    def revision(name: str, rate: int) -> Path:
        folder = tmp_path / name
        folder.mkdir()
        (folder / "shared_rates.py").write_text(f"RATE = {rate}\n")
        (folder / "test_case.py").write_text(
            "from redline.testing import Cartesian, Phase, Sleep, TestCase\n"
            "from shared_rates import RATE\n"
            "case = TestCase('load', [Phase('p', Sleep(0))], Cartesian(rate=[RATE]))\n"
        )
        return folder / "test_case.py"

    first = load_test_cases([revision("r1", 10)])
    second = load_test_cases([revision("r2", 20)])
    assert [s["rate"] for s in first[0].parameter_sets()] == [10]
    assert [s["rate"] for s in second[0].parameter_sets()] == [20]


def test_placeholders_in_commands_are_substituted_and_other_braces_left_alone(
    tmp_path: Path,
) -> None:
    command = (
        'command = ["python", "demo.py", "--config", "{zenoh_config}", '
        '\'{"a": {"b": 1}}\', "{{zenoh_config}}", "${HOME}", "c={zenoh_config}"]'
    )
    text = VALID.replace('command = ["python", "demo.py"]', command)
    (component,) = load_suite(write(tmp_path, text)).components
    assert component.command[3] == "{zenoh_config}"  # substituted when the run knows the path
    expanded = component.expanded({"zenoh_config": "/run/zenoh.json"})
    assert expanded.command[2:] == (
        "--config",
        "/run/zenoh.json",
        '{"a": {"b": 1}}',
        "{zenoh_config}",
        "${HOME}",
        "c=/run/zenoh.json",
    )
    assert expanded.name == component.name and expanded.ready == component.ready


def test_an_unknown_placeholder_is_named_with_file_line_and_the_known_ones(tmp_path: Path) -> None:
    text = VALID.replace(
        'command = ["python", "demo.py"]',
        'command = ["python", "demo.py", "--config", "{zenoh_cfg}"]',
    )
    message = error_of(tmp_path, text)
    assert message.startswith(f"{tmp_path / 'redline.toml'}:6: [[component]] #1:")
    assert "unknown placeholder {zenoh_cfg}" in message and "{zenoh_config}" in message
    assert "{{zenoh_cfg}}" in message  # how to write it literally
    fixture = VALID + '\n[[fixture]]\nname = "map"\ncommand = ["map", "{map_file}"]\n'
    assert error_of(tmp_path, fixture).startswith(f"{tmp_path / 'redline.toml'}:11: [[fixture]]")


def test_suite_transport_is_checked_and_names_its_line(tmp_path: Path) -> None:
    transport = VALID.replace("\n\n[[component]]", '\ntransport = "TRANSPORT"\n\n[[component]]')
    assert load_suite(write(tmp_path, transport.replace("TRANSPORT", "unix"))).transport == "unix"
    message = error_of(tmp_path, transport.replace("TRANSPORT", "udp"))
    assert "redline.toml:3: 'transport' must be one of 'tcp', 'unix', got 'udp'" in message
