"""Bad input to a run found before anything starts: a clear error naming what is wrong, and no
process started."""

from __future__ import annotations

from pathlib import Path

import pytest
from redline.agent.runner import run_suite
from redline.agent.suite import SuiteError
from redline.testing import ValidationError

from tests.support.suites import quiet_suite as _suite

pytestmark = pytest.mark.usefixtures("workspaces_in_tmp_path")


def test_missing_parameter_fails_before_any_process_starts(tmp_path: Path) -> None:
    suite = _suite(
        tmp_path,
        """\
        from redline.testing import Cartesian, FixedRate, Param, Phase, Publish, TestCase
        case = TestCase("c", [Phase("p", FixedRate(Param("rate"), 1, Publish("k", b"")))],
                        Cartesian(rat=[1]))
        """,
    )
    with pytest.raises(ValidationError, match="phase 'p': parameter 'rate' is missing"):
        run_suite(suite, tmp_path / "out.mcap")
    assert not (tmp_path / "out.mcap").exists() and not (tmp_path / "pid").exists()


def test_malformed_key_expression_fails_before_any_process_starts(tmp_path: Path) -> None:
    suite = _suite(
        tmp_path,
        """\
        from redline.testing import Phase, Publish, TestCase
        case = TestCase("c", [Phase("p", Publish("robot//scan", b""))])
        """,
    )
    with pytest.raises(ValidationError, match="'robot//scan' is not a valid key expression"):
        run_suite(suite, tmp_path / "out.mcap")
    assert not (tmp_path / "pid").exists()


def test_test_module_with_an_error_is_named_with_its_line(tmp_path: Path) -> None:
    suite = _suite(
        tmp_path,
        """\
        from redline.testing import Phase, Static, TestCase
        case = TestCase("c", [Phase("p", Static(1))])
        broken = 1 / 0
        """,
    )
    with pytest.raises(  # bad input, as a bad suite file is: `redline run` exits 2
        SuiteError,
        match=r"test_it.py:3: cannot import test module: "
        r"ZeroDivisionError",
    ):
        run_suite(suite, tmp_path / "out.mcap")
