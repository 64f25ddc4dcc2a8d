"""Two runs on one host at the same time never see each other's traffic.

Each run has its own zenoh router on its own loopback port, and its components get a peer
configuration with multicast scouting off. Here two runs of a chatty peer component go at once;
each recording must hold its own component's and driver's samples and nothing of the other's.
"""

from __future__ import annotations

import tempfile
import textwrap
import threading
import time
from pathlib import Path

import pytest
from redline.agent.network import RunNetwork
from redline.agent.runner import RunResult, run_suite
from redline.recording import read_recording

COMPONENT = """\
    import os, signal, threading, zenoh
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: threading.Thread(target=stop.set).start())
    with zenoh.open(zenoh.Config.from_env()) as session:
        heard = session.declare_subscriber("iso/**", lambda s: None)  # a peer that listens too
        print("component ready", flush=True)
        while not stop.wait(0.05):
            session.put(f"iso/component/{os.getpid()}", b"alive")
    """

TEST = """\
    from redline.testing import FixedRate, Param, Phase, Publish, TestCase, Cartesian
    case = TestCase("talk", [Phase("p", FixedRate(50, 1.0, Publish(Param("key"), b"x")))],
                    Cartesian(key=["iso/driver/unset"]))
    """


def _suite(folder: Path, transport: str = "tcp") -> Path:
    folder.mkdir()
    (folder / "component.py").write_text(textwrap.dedent(COMPONENT))
    (folder / "test_iso.py").write_text(textwrap.dedent(TEST))
    path = folder / "redline.toml"
    path.write_text(
        textwrap.dedent("""\
        name = "iso"
        tests = ["test_iso.py"]
        transport = "{transport}"
        [[component]]
        name = "chatty"
        command = ["python", "component.py"]
        ready = { log = "component ready" }
        """).replace("{transport}", transport)
    )
    return path


@pytest.mark.parametrize("transport", ["tcp", "unix"])
def test_two_simultaneous_runs_record_only_their_own_traffic(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, transport: str
) -> None:
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    results: dict[str, RunResult] = {}
    errors: list[BaseException] = []

    def run(name: str) -> None:
        try:
            results[name] = run_suite(
                _suite(tmp_path / name, transport),
                tmp_path / f"{name}.mcap",
                overrides={"key": f"iso/driver/{name}"},
            )
        except BaseException as exc:  # reported by the main thread
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(name,)) for name in ("a", "b")]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not errors, errors
    for own, other in (("a", "b"), ("b", "a")):
        recording = read_recording(results[own].recording)
        pids = {c["pid"] for c in recording.counters if c["process"] == "chatty"}
        keys = set(recording.traffic)
        assert keys == {f"iso/driver/{own}", f"iso/component/{pids.pop()}"}, keys
        assert recording.traffic[f"iso/driver/{own}"] == 50
        assert [m["params"]["key"] for m in recording.markers] == [f"iso/driver/{own}"] * 2
        assert not [k for k in keys if other in k]
        counts = recording.metadata["redline.recorder"]  # the driver's 50 puts were all recorded
        assert counts["checked_keys"] == "1" and counts["lost"] == "0", counts
        assert counts["zenoh_shared_memory"] == "on"
        assert counts["zenoh_endpoint"].startswith(
            {"tcp": "tcp/127.0.0.1:", "unix": "unixsock-stream/"}[transport]
        )


def test_unix_transport_uses_a_socket_and_no_port(tmp_path: Path) -> None:
    with RunNetwork(transport="unix") as network:
        assert network.endpoint.startswith("unixsock-stream/")
        socket_path = Path(network.endpoint.split("/", 1)[1])
        assert socket_path.is_socket()
        peer = network.peer_settings()
        assert peer["listen"]["endpoints"] == [] and peer["connect"]["endpoints"] == [
            network.endpoint
        ]
    assert not socket_path.parent.exists()  # the private folder goes with the network


def test_a_port_taken_between_choosing_and_binding_it_is_chosen_again(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A CI run's three agents on one host failed a job with zenoh's "Address already in use":
    the port its router chose free was taken before the router bound it. The router chooses
    again; a port the caller named is not moved."""
    import socket

    import zenoh
    from redline.agent import network

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        chosen = iter([port])  # the first choice is taken by the time the router binds it
        free = network.free_port
        monkeypatch.setattr(network, "free_port", lambda: next(chosen, None) or free())
        with RunNetwork() as run:
            assert run.endpoint.startswith("tcp/127.0.0.1:")
            assert run.endpoint != f"tcp/127.0.0.1:{port}"
            # a client reaches it there: the router hears its session
            zid = network.session_id()
            with zenoh.open(network.config_from_dict(run.client_settings(zid))):
                deadline = time.monotonic() + 5
                while zid not in run.sessions_seen() and time.monotonic() < deadline:
                    time.sleep(0.05)
            assert zid in run.sessions_seen()
        with pytest.raises(zenoh.ZError, match="Address already in use"):
            RunNetwork(port).open()
