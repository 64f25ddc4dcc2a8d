"""A tiny component for tests that run real agents: it idles, and its suite is one one-second
phase, so that a job takes seconds; its build step hangs for agents whose work folder is named
``slow-*``, which is how a test holds an agent in the middle of a job."""

from __future__ import annotations

import textwrap
from pathlib import Path

from tests.support.git import committed_repo

SUITE = """\
    name = "tiny"
    tests = ["test_tiny.py"]
    build = ["python", "build.py"]
    [[component]]
    name = "tiny"
    command = ["python", "component.py"]
    ready = { log = "tiny ready" }
    """
FILES = {
    "perf/redline.toml": SUITE,
    "perf/component.py": """\
        import os, time
        print("tiny ready; the agent's token in my environment:", "REDLINE_TOKEN" in os.environ,
              flush=True)
        while True:
            time.sleep(0.05)
        """,
    "perf/test_tiny.py": """\
        from redline.testing import Phase, Sleep, TestCase
        idle = TestCase("idle", [Phase("idle", Sleep(1.0))])
        """,
    "perf/build.py": """\
        import os, time
        if "/slow-" in os.getcwd():  # the tests' way of holding an agent mid-job
            time.sleep(600)
        """,
}


#: the tiny component answering queries, and a suite that asks them: its runs take part in the
#: network (status ok, not no_traffic), so their round trips and the component's CPU are judged
ANSWERING = {
    "perf/component.py": """\
        import time, zenoh
        with zenoh.open(zenoh.Config.from_env()) as session:
            def answer(query):
                with query:  # a query must be finished, or the caller waits for its timeout
                    query.reply("tiny/ping", b"pong")
            session.declare_queryable("tiny/ping", answer)
            print("tiny ready", flush=True)
            while True:
                time.sleep(0.05)
        """,
    "perf/test_tiny.py": """\
        from redline.testing import FixedRate, Message, Phase, Query, TestCase
        PING = Query("tiny/ping", Message.raw(8), timeout=1.0)
        ping = TestCase("ping", [Phase("steady", FixedRate(50, 2.0, PING))])
        """,
}


def tiny_repo(path: Path, answering: bool = False) -> tuple[Path, str]:
    """The tiny component's repository at ``path``, and its commit; ``answering``: the
    component answers the suite's queries (`ANSWERING`) instead of idling unheard."""
    files = {**FILES, **(ANSWERING if answering else {})}
    return committed_repo(path, {name: textwrap.dedent(text) for name, text in files.items()})


def agent_args(server: str, name: str, work: Path) -> list[str]:
    """`redline agent`'s arguments (after `redline`) for a test's agent: it looks for jobs every
    half second, waits 2 s for one, and lets a job it runs end (grace) rather than a test's
    signal stop it half-way."""
    return ["agent", "--server", server, "--name", name, "--work", str(work),
            "--poll", "0.5", "--wait", "2", "--grace", "300"]  # fmt: skip
