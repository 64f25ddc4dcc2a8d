"""Loading a suite's test modules from their file paths and collecting their test cases."""

from __future__ import annotations

import hashlib
import importlib.util
import sys
import traceback
from pathlib import Path
from types import ModuleType

from redline.agent.suite import SuiteError
from redline.testing import TestCase
from redline.testing.replay import LOADING_FROM


def _where(exc: BaseException, path: Path) -> str:
    """``path:line`` of the deepest frame of ``exc`` inside the test module (or just the path)."""
    if isinstance(exc, SyntaxError) and exc.lineno:
        return f"{path}:{exc.lineno}"
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if Path(f.filename) == path]
    return f"{path}:{frames[-1].lineno}" if frames else str(path)


def import_module(path: Path) -> ModuleType:
    """Import a test module from its file; its directory is importable while it loads.

    Nothing it brings in from its own folder stays cached in ``sys.modules`` afterwards: a
    long-lived agent loads one revision's suite after another, and a sibling module imported by
    name (``from helpers import ...``) must come from the revision being run, not a former one.
    """
    name = "redline_tests_" + hashlib.sha1(str(path).encode()).hexdigest()[:12]
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise SuiteError(f"{path}: cannot be imported as a Python module")
    module = importlib.util.module_from_spec(spec)
    before = set(sys.modules)
    sys.modules[name] = module
    sys.path.insert(0, str(path.parent))
    loading = LOADING_FROM.set(path.parent.resolve())  # where its `Replay`s find recordings
    try:
        spec.loader.exec_module(module)
    except Exception as exc:
        detail = "".join(traceback.format_exception_only(exc)).strip()
        raise SuiteError(f"{_where(exc, path)}: cannot import test module: {detail}") from exc
    finally:
        LOADING_FROM.reset(loading)
        sys.path.remove(str(path.parent))
        _forget_modules_from(path.parent, set(sys.modules) - before)
        sys.modules.pop(name, None)
    return module


def _forget_modules_from(folder: Path, names: set[str]) -> None:
    """Drop the newly imported modules whose file lies in ``folder`` from the module cache."""
    for loaded in names:
        origin = getattr(sys.modules.get(loaded), "__file__", None)
        if origin and Path(origin).resolve().is_relative_to(folder.resolve()):
            del sys.modules[loaded]


def load_test_cases(paths: tuple[Path, ...] | list[Path]) -> list[TestCase]:
    """Every `TestCase` defined at the top level of the modules, in module and definition order."""
    cases: list[TestCase] = []
    for path in paths:
        found = [v for v in vars(import_module(path)).values() if isinstance(v, TestCase)]
        if not found:
            raise SuiteError(f"{path}: defines no TestCase at its top level")
        cases.extend(case for case in found if all(case is not c for c in cases))
    return cases
