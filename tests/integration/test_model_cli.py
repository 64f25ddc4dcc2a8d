"""`redline model fit` and `redline model score` as real commands in their own processes, on
recordings written by the real writer (`tests/support/predict.py`)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from redline.predict.dataset import dataset, read_run
from redline.predict.model import ModelFile

from tests.support.predict import SMALL, record

pytestmark = pytest.mark.slow

REDLINE = str(Path(sys.executable).parent / "redline")


def test_the_command_line_fits_and_scores(tmp_path):
    for i in (1, 2):
        record(tmp_path / f"t{i}.mcap", [1, 5, 9, 13], seed=i)
    record(tmp_path / "test.mcap", [3, 7, 11], seed=5)
    model = tmp_path / "m.joblib"
    fitted = subprocess.run(
        [REDLINE, "model", "fit", str(tmp_path / "t1.mcap"), str(tmp_path / "t2.mcap"),
         "--out", str(model)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert fitted.returncode == 0, fitted.stderr
    assert "cpu_percent: cross-validated RMSE" in fitted.stdout
    scored = subprocess.run(
        [REDLINE, "model", "score", str(model), str(tmp_path / "test.mcap"), "--json"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert scored.returncode == 0, scored.stderr
    found = json.loads(scored.stdout)
    assert set(found) == {"cpu_percent", "rss_bytes"}
    assert found["cpu_percent"]["ratio"] < 0.3
    assert set(found["cpu_percent"]) == {"rmse", "baseline_rmse", "ratio"}
    assert found["rss_bytes"]["ratio"] is None  # constant RSS: no baseline to compare with


def test_unseen_keys_are_named_and_ignored_and_no_traffic_is_exit_2(tmp_path):
    model = ModelFile.fit(
        dataset([read_run(record(tmp_path / f"f{i}.mcap", [1, 4, 8], seed=i)) for i in (1, 2)]),
        SMALL,
    )
    path = tmp_path / "m.joblib"
    model.save(path)
    silent = record(tmp_path / "silent.mcap", [1, 2], traffic=False)
    record(tmp_path / "new.mcap", [2, 6], seed=3, extra="robot/debug")
    scored = subprocess.run(
        [REDLINE, "model", "score", str(path), str(tmp_path / "new.mcap"), "--json"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert scored.returncode == 0, scored.stderr
    assert "never saw these keys and ignores them: robot/debug" in scored.stderr
    assert json.loads(scored.stdout)["cpu_percent"]["ratio"] < 0.5
    empty = subprocess.run(
        [REDLINE, "model", "score", str(path), str(silent)], capture_output=True, text=True
    )
    assert empty.returncode == 2 and "holds no traffic" in empty.stderr
