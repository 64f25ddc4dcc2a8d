"""A component that ignores the run's zenoh network is never a silent pass.

The component here is real: with ``--own-network`` it opens zenoh with an isolated configuration
of its own on another port (it ignores ``ZENOH_CONFIG``), as the component of the report did.
The runner must say so loudly (console, exit code 3, the recording's status ``no_traffic`` with
a ``warning``), and the server, ingesting such a recording through the real worker path, must
answer "not enough data" with that reason instead of judging its series.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from redline.agent.runner import RunResult, run_suite
from redline.recording import read_recording
from redline.server.models import Detection, Execution, Revision, Summary
from redline.server.schemas.components import ComponentCreate
from redline.server.schemas.revisions import RevisionCreate
from redline.server.services.compare import compare
from redline.server.services.components import create_component
from redline.server.services.revisions import create_revision
from redline.worker.detection import detect_revision
from redline.worker.ingest import ingest_execution
from sqlalchemy import select

from tests.support.history import uploaded

COMPONENT = """\
    import argparse, json, signal, socket, threading, zenoh

    parser = argparse.ArgumentParser()
    parser.add_argument("--own-network", action="store_true")
    parser.add_argument("--serve", default="svc/ping")
    parser.add_argument("--listen", help="subscribe to this key, publish nothing (a sink)")
    parser.add_argument("--echo", action="store_true", help="put each svc/in sample on svc/out")
    args = parser.parse_args()
    if args.own_network:  # ignores ZENOH_CONFIG: a network of its own on another port
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        config = zenoh.Config()
        config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
        config.insert_json5("scouting/multicast/enabled", "false")
    else:
        config = zenoh.Config.from_env()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: threading.Thread(target=stop.set).start())

    def answer(query):
        with query:
            query.reply(args.serve, b"pong")

    with zenoh.open(config) as session:
        session.declare_queryable(args.serve, answer)
        if args.listen:
            session.declare_subscriber(args.listen, lambda sample: None)
        if args.echo:
            session.declare_subscriber("svc/in", lambda s: session.put("svc/out", s.payload))
        print("svc ready", flush=True)
        while not stop.wait(0.1):
            pass
    """

QUERIES = """\
    from redline.testing import FixedRate, Phase, Query, TestCase
    PING = Query("svc/ping", b"x", timeout=0.2)
    case = TestCase("ping", [Phase("warm", FixedRate(50, 0.3, PING), warmup=True),
                             Phase("steady", FixedRate(50, 1.5, PING))])
    """

PUBLISHES = """\
    from redline.testing import FixedRate, Phase, Publish, TestCase
    case = TestCase("feed", [Phase("steady", FixedRate(50, 1.0, Publish("svc/in", b"x")))])
    """

WAITS = """\
    from redline.testing import FixedRate, Phase, Publish, TestCase, WaitFor
    ECHO = WaitFor("svc/out", 0.2, after=Publish("svc/in", b"x"))
    case = TestCase("echo", [Phase("steady", FixedRate(5, 1.0, ECHO))])
    """


def _suite(folder: Path, test: str, *args: str) -> Path:
    folder.mkdir(parents=True)
    (folder / "svc.py").write_text(textwrap.dedent(COMPONENT))
    (folder / "test_svc.py").write_text(textwrap.dedent(test))
    command = ", ".join(f'"{arg}"' for arg in ("python", "svc.py", *args))
    (folder / "redline.toml").write_text(
        textwrap.dedent(f"""\
        name = "svc"
        tests = ["test_svc.py"]
        sampling_hz = 20
        [[component]]
        name = "svc"
        command = [{command}]
        ready = {{ log = "svc ready" }}
        """)
    )
    return folder / "redline.toml"


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    """A good run (the Python API), and `redline run` of the component on its own network."""
    folder = tmp_path_factory.mktemp("no-traffic")
    good = run_suite(_suite(folder / "good", QUERIES), folder / "good.mcap")
    deaf = _suite(folder / "deaf", QUERIES, "--own-network")
    redline = str(Path(sys.executable).parent / "redline")
    done = subprocess.run(
        [redline, "run", str(deaf), "--out", str(folder / "deaf.mcap")],
        capture_output=True,
        text=True,
        timeout=180,
        env={**os.environ, "COLUMNS": "200"},
    )
    return {"good": good, "deaf": folder / "deaf.mcap", "cli": done}


def test_redline_run_warns_exits_3_and_records_no_traffic_for_a_component_on_its_own_network(
    runs: dict[str, object],
) -> None:
    done = runs["cli"]
    assert isinstance(done, subprocess.CompletedProcess)
    assert done.returncode == 3, done.stderr
    assert "WARNING" in done.stderr and "no traffic" in done.stderr
    run = read_recording(runs["deaf"]).run
    assert run["status"] == "no_traffic"
    assert "no process of the suite joined the run's zenoh network" in run["warning"]
    assert "none of the 75 queries of the measured phases was answered" in run["warning"]


def test_a_component_on_the_network_that_answers_no_query_is_no_traffic(tmp_path: Path) -> None:
    suite = _suite(tmp_path / "other", QUERIES, "--serve", "svc/other")
    result = run_suite(suite, tmp_path / "other.mcap")
    assert result.run_metadata["status"] == "no_traffic"
    assert result.run_metadata["warning"] == (
        "none of the 75 queries of the measured phases was answered"
    )


def test_a_component_off_the_network_is_no_traffic_without_any_query(tmp_path: Path) -> None:
    suite = _suite(tmp_path / "feed", PUBLISHES, "--own-network")
    run = read_recording(run_suite(suite, tmp_path / "feed.mcap").recording).run
    assert run["status"] == "no_traffic"
    assert run["warning"].startswith("no process of the suite joined the run's zenoh network")
    assert "queries" not in run["warning"]


def test_a_component_on_the_network_that_publishes_and_hears_nothing_is_no_traffic(
    tmp_path: Path,
) -> None:
    """It joins the run's network (a queryable nobody asks) but neither subscribes to what the
    publish-only tests send nor puts a sample of its own: it took no part in them."""
    suite = _suite(tmp_path / "deaf", PUBLISHES)
    run = read_recording(run_suite(suite, tmp_path / "deaf.mcap").recording).run
    assert run["status"] == "no_traffic"
    assert run["warning"] == (
        "the component published nothing on the run's network, nor subscribed to what the "
        "tests published (svc/in)"
    )


def test_a_sink_that_subscribes_to_what_the_tests_publish_is_not_flagged(tmp_path: Path) -> None:
    suite = _suite(tmp_path / "sink", PUBLISHES, "--listen", "svc/*")
    run = read_recording(run_suite(suite, tmp_path / "sink.mcap").recording).run
    assert run["status"] == "ok" and "warning" not in run


def test_a_component_whose_samples_the_tests_wait_for_in_vain_is_no_traffic(
    tmp_path: Path,
) -> None:
    silent = _suite(tmp_path / "silent", WAITS, "--listen", "svc/in")
    result = run_suite(silent, tmp_path / "silent.mcap")
    assert result.run_metadata["status"] == "no_traffic"
    assert result.run_metadata["warning"] == (
        "no sample arrived on svc/out, which the measured phases waited for 5 time(s)"
    )
    echo = _suite(tmp_path / "echo", WAITS, "--echo")
    assert run_suite(echo, tmp_path / "echo.mcap").run_metadata["status"] == "ok"


def test_a_good_run_has_no_warning(runs: dict[str, object]) -> None:
    good = runs["good"]
    assert isinstance(good, RunResult)
    run = read_recording(good.recording).run
    assert run["status"] == "ok" and "warning" not in run


def _execution(session, title: str, sort_key: str, recording: Path) -> Execution:
    """Report a revision of 'svc' and store ``recording`` for its job, as an upload would."""
    revision = create_revision(
        session, RevisionCreate(component="svc", title=title, sort_key=sort_key, commit="main")
    )
    (job,) = revision.jobs
    execution = uploaded(session, job, recording, title)
    session.commit()
    return execution


def _every_verdict(session, title: str) -> list[Detection]:
    session.expire_all()
    return list(
        session.scalars(
            select(Detection)
            .join(Revision, Revision.id == Detection.revision_id)
            .where(Revision.title == title)
        )
    )


def test_the_worker_answers_not_enough_data_with_the_reason_for_a_no_traffic_execution(
    runs: dict[str, object], session, database_url: str
) -> None:
    create_component(session, ComponentCreate(name="svc"))
    good_run, deaf_recording = runs["good"], runs["deaf"]
    assert isinstance(good_run, RunResult) and isinstance(deaf_recording, Path)
    good = _execution(session, "r1", "1", good_run.recording)
    deaf = _execution(session, "r2", "2", deaf_recording)
    for execution in (good, deaf):
        ingest_execution(database_url, execution.id)
        detect_revision(database_url, execution.revision_id)
    found = _every_verdict(session, "r2")
    assert found, "r2 got no detection at all"
    series = {d.series_id for d in found}
    assert {d.verdict for d in found} == {"not enough data"}
    assert all(d.reason.startswith("no traffic: no process of the suite joined") for d in found)
    assert all("none of the 75 queries" in d.reason for d in found)
    assert session.scalars(select(Summary).where(Summary.execution_id == deaf.id)).all() == []
    judged = {d.series_id for d in _every_verdict(session, "r1")}
    assert series <= judged  # the same series, judged (missing baseline) for the good run
    assert compare(session, "svc", "r1", "r2").series == []  # its samples compare with nothing
