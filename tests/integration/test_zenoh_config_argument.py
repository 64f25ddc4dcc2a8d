"""A component that takes its zenoh configuration as ``--config FILE``, as every official
eclipse-zenoh example does, runs through the suite's ``{zenoh_config}`` placeholder."""

from __future__ import annotations

import tempfile
import textwrap
from pathlib import Path

import pytest
from redline.agent.runner import run_suite
from redline.recording import read_recording

# The shape of eclipse-zenoh's examples (z_queryable.py): argparse, --config/-c FILE, and
# zenoh.Config.from_file; without --config it would open zenoh's default configuration, which
# cannot reach the run's isolated network.
Z_QUERYABLE = """\
    import argparse, signal, threading, zenoh

    parser = argparse.ArgumentParser(prog="z_queryable", description="zenoh queryable example")
    parser.add_argument("--config", "-c", dest="config", metavar="FILE", type=str,
                        help="A configuration file.")
    parser.add_argument("--key", "-k", dest="key", default="demo/example/queryable", type=str)
    args = parser.parse_args()
    conf = zenoh.Config.from_file(args.config) if args.config else zenoh.Config()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: threading.Thread(target=stop.set).start())

    def answer(query):
        with query:
            query.reply(args.key, b"from z_queryable")

    with zenoh.open(conf) as session:
        session.declare_queryable(args.key, answer)
        print(f"Declaring Queryable on '{args.key}'...", flush=True)
        while not stop.wait(0.1):
            pass
    """

TEST = """\
    from redline.testing import FixedRate, Phase, Query, TestCase
    case = TestCase("ask", [Phase("steady", FixedRate(20, 1.0, Query("demo/example/queryable",
                                                                     timeout=1.0)))])
    """


def test_a_zenoh_example_style_program_gets_the_run_configuration_as_config_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    (tmp_path / "z_queryable.py").write_text(textwrap.dedent(Z_QUERYABLE))
    (tmp_path / "test_ask.py").write_text(textwrap.dedent(TEST))
    suite = tmp_path / "redline.toml"
    suite.write_text(
        textwrap.dedent("""\
        name = "example"
        tests = ["test_ask.py"]
        [[component]]
        name = "z_queryable"
        command = ["python", "z_queryable.py", "--config", "{zenoh_config}"]
        ready = { log = "Declaring Queryable" }
        start_timeout = 10
        """)
    )
    recording = read_recording(run_suite(suite, tmp_path / "out.mcap").recording)
    assert recording.run["status"] == "ok"
    (report,) = [d for d in recording.driver if d["action"] == "Query"]
    assert report["queries"] == report["count"] == 20  # every query answered on the run's network
