"""The CI examples of docs/ci.md, run: every shell step of the GitHub Actions, GitLab CI and
Jenkins examples, in order, in bash, with the variables each CI system would set, against a live
server on real Postgres. The test plays the performance host between the report and the wait
steps (a recording stored for the revision's job, ingested and judged), and checks each wait
step's exit code and the JUnit file it leaves. The GitHub and GitLab examples run a second time
as with their forge's push webhook: the push reports the revision, the report step is left
out (and the install step too: the environment of the run before it of that example is
reused, as a runner's cache would)."""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import re
import subprocess
import sys
from pathlib import Path
from xml.etree import ElementTree

import httpx
import numpy as np
import pytest
import yaml
from redline.server.db import session_factory
from redline.server.models import Component, Execution, Job, JobState, Revision
from redline.worker.detection import detect_revision
from redline.worker.ingest import ingest_execution
from sqlalchemy import select

from tests.support.api import api_with
from tests.support.git import GIT
from tests.support.history import cpu_history, ingest_and_detect
from tests.support.recordings import run_metadata, write_recording
from tests.support.servers import live_server

ROOT = Path(__file__).parents[2]
DOC = (ROOT / "docs" / "ci.md").read_text()
SECRET = "push-secret"
REPORT = "redline ci report"  # what the report step runs
INSTALL = "python3 -m venv .redline"  # what the install step begins with


def _block(heading: str) -> str:
    """The first fenced code block after ``heading``."""
    after = DOC[DOC.index(heading) :]
    return re.search(r"```\w+\n(.*?)```", after, re.S).group(1)


def github_steps() -> list[str]:
    job = yaml.safe_load(_block("### GitHub Actions"))["jobs"]["redline"]
    return [step["run"] for step in job["steps"] if "run" in step]


def gitlab_steps() -> list[str]:
    return yaml.safe_load(_block("### GitLab CI"))["redline"]["script"]


def jenkins_steps() -> list[str]:
    found = re.findall(r"sh '''(.*?)'''|sh '([^'\n]*)'", _block("### Jenkins"), re.S)
    # Groovy joins a line ending in a backslash with the next, inside ''' strings
    return [(long or short).replace("\\\n", "") for long, short in found]


EXAMPLES = {
    "github": (github_steps, ("GITHUB_SHA", "GITHUB_RUN_NUMBER", "GITHUB_REF_NAME")),
    "gitlab": (gitlab_steps, ("CI_COMMIT_SHA", "CI_PIPELINE_IID", "CI_COMMIT_BRANCH")),
    "jenkins": (jenkins_steps, ("GIT_COMMIT", "BUILD_NUMBER", "BRANCH_NAME")),
}


@pytest.fixture(scope="module")
def server(services, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("examples")
    with api_with(services, tmp, read_access="token", webhook_secret=SECRET) as api:
        with session_factory(api.settings.database_url)() as session:
            executions = cpu_history(session, tmp, [10.0] * 5, config={"methods": ["ks"]})
            session.execute(
                Component.__table__.update().values(
                    repo="https://github.com/robots/builder",
                    repo_key="github.com/robots/builder",
                    suite="perf/redline.toml",
                )
            )
            session.commit()
        ingest_and_detect(api.settings.database_url, executions)
        # where "the organisation keeps" redline-agent (docs/ci.md): a wheel of this checkout
        # and of what it needs, made once, from which the four examples' installs take theirs
        # without asking the package index again (`run_example`)
        wheels = tmp / "wheels"
        subprocess.run(
            [sys.executable, "-m", "pip", "wheel", "--quiet", "-w", str(wheels),
             str(ROOT / "agent")],
            check=True, capture_output=True, timeout=300,
        )  # fmt: skip
        (wheel,) = wheels.glob("redline_agent-*.whl")
        with live_server(api.settings) as url:
            # each install step's command run so far, and the environment it made
            installed: dict[str, Path] = {}
            yield url, api, tmp, wheel, installed


def play_host(api, tmp: Path, title: str, cpu: float) -> None:
    """What a performance host and the worker do: run the job, store its recording, judge."""
    database_url = api.settings.database_url
    with session_factory(database_url)() as session:
        revision = session.scalar(select(Revision).where(Revision.title == title))
        assert revision is not None, f"the report step made no revision {title}"
        (job,) = session.scalars(select(Job).where(Job.revision_id == revision.id))
        values = np.random.default_rng(len(title)).normal(cpu, cpu / 20, 60)
        path = write_recording(
            tmp / f"{title}.mcap",
            run_metadata(job, "builder", title, revision.sort_key),
            {"cpu": values},
        )
        execution = Execution(
            job_id=job.id,
            revision_id=revision.id,
            recording_path=str(path),
            sha256=hashlib.sha256(path.read_bytes()).hexdigest(),
            size=path.stat().st_size,
        )
        job.state = JobState.uploaded
        session.add(execution)
        session.commit()
        ingest_execution(database_url, execution.id)
        detect_revision(database_url, revision.id)


def run_example(server, name: str, number: int, cpu: float, webhook: str = "") -> int:
    """Every step of the example in order, as its CI system would; returns the wait step's exit
    code (the JUnit file is checked by the caller)."""
    url, api, tmp, wheel, installed = server
    steps, (sha_var, number_var, branch_var) = EXAMPLES[name]
    workspace = tmp / f"{name}-{number}"
    workspace.mkdir()
    # the CI system's checkout: its commit's time is the report's sort key, an hour apart from
    # one example to the next and before the push the webhook run sends (2026-11-22)
    when = {"GIT_AUTHOR_DATE": f"2026-11-20T{number:02d}:00:00Z"}
    subprocess.run([*GIT, "init", "-q"], cwd=workspace, check=True)
    subprocess.run(
        [*GIT, "commit", "-q", "--allow-empty", "-m", "m"],
        cwd=workspace,
        check=True,
        env={**os.environ, **when, "GIT_COMMITTER_DATE": when["GIT_AUTHOR_DATE"]},
    )
    sha = subprocess.run(
        [*GIT, "rev-parse", "HEAD"], cwd=workspace, check=True, capture_output=True, text=True
    ).stdout.strip()  # what the CI system checked out, and names in its variable
    env = {
        "PATH": os.environ["PATH"],
        "HOME": str(workspace),
        "REDLINE_SERVER": url,
        "REDLINE_TOKEN": api.tokens["ci"]["Authorization"].removeprefix("Bearer "),
        "REDLINE_AGENT": str(wheel),
        "COMPONENT": "builder",  # the examples' component is the CI system's setting
        # the agent and its dependencies from the wheels made once, as a CI runner's cache or
        # the organisation's own index would serve them (each HOME is new)
        "PIP_NO_INDEX": "1",
        "PIP_FIND_LINKS": str(wheel.parent),
        "PIP_DISABLE_PIP_VERSION_CHECK": "1",
        sha_var: sha,
        number_var: str(number),
        branch_var: "main",
    }
    if webhook:
        answer = send_push(url, webhook, sha)
        assert answer.status_code == 200 and answer.json()["created"], answer.text
        play_host(api, tmp, sha[:12], cpu)
    waited = None
    for script in steps():
        if webhook and REPORT in script:
            continue
        if INSTALL in script and script in installed:
            # the very command an example before this one ran, in a workspace of its own: its
            # environment is reused, as a runner's cache would (each install took 20 s of the
            # suite's CPU; the three examples' install steps are one command)
            (workspace / ".redline").symlink_to(installed[script])
            continue
        done = subprocess.run(
            ["bash", "-e", "-c", script],
            cwd=workspace,
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        if "ci wait" in script:
            waited = done.returncode
            assert done.returncode in (0, 1), done.stderr + done.stdout
            continue
        assert done.returncode == 0, f"{name}: {script}\n{done.stderr}"
        if INSTALL in script:
            installed[script] = workspace / ".redline"
        if REPORT in script:
            play_host(api, tmp, sha[:12], cpu)
    assert waited is not None, f"{name}: no wait step"
    return waited


def send_push(url: str, forge: str, sha: str) -> httpx.Response:
    """The push webhook ``forge`` (github or gitlab) sends for one commit, as docs/ci.md section
    3 sets it up: GitHub signs the body with the secret, GitLab sends the secret as its token."""
    commits = [{"id": sha, "message": "m", "timestamp": "2026-11-22T10:00:00Z"}]
    if forge == "github":
        push = json.dumps(
            {
                "ref": "refs/heads/main",
                "commits": commits,
                "repository": {"clone_url": "https://github.com/robots/builder.git"},
            }
        ).encode()
        signature = "sha256=" + hmac.new(SECRET.encode(), push, hashlib.sha256).hexdigest()
        headers = {"X-Hub-Signature-256": signature, "X-GitHub-Event": "push"}
    else:
        push = json.dumps(
            {
                "object_kind": "push",
                "ref": "refs/heads/main",
                "commits": commits,
                "project": {"git_http_url": "https://github.com/robots/builder.git"},
            }
        ).encode()
        headers = {"X-Gitlab-Token": SECRET, "X-Gitlab-Event": "Push Hook"}
    return httpx.post(
        f"{url}/api/v1/webhooks/{forge}",
        content=push,
        headers={**headers, "Content-Type": "application/json"},
    )


def junit(server, name: str, number: int) -> ElementTree.Element:
    return ElementTree.parse(server[2] / f"{name}-{number}" / "redline.xml").getroot()


@pytest.mark.slow
def test_each_example_reports_waits_and_leaves_its_junit_report(server):
    assert run_example(server, "github", 6, cpu=10.0) == 0
    assert junit(server, "github", 6).get("failures") == "0"
    assert run_example(server, "gitlab", 7, cpu=10.0) == 0
    assert junit(server, "gitlab", 7).get("failures") == "0"
    # a change for the worse fails the Jenkins build
    assert run_example(server, "jenkins", 8, cpu=15.0) == 1
    assert junit(server, "jenkins", 8).get("failures") == "1"
    # with the push webhook instead of the report step: the same level as r8, no change
    assert run_example(server, "github", 9, cpu=15.0, webhook="github") == 0
    suite = junit(server, "github", 9)
    assert (suite.get("tests"), suite.get("failures")) == ("1", "0")
    # GitLab's push hook reporting the revision, the GitLab CI example waiting: a change
    # for the worse fails the pipeline
    assert run_example(server, "gitlab", 10, cpu=25.0, webhook="gitlab") == 1
    assert junit(server, "gitlab", 10).get("failures") == "1"
