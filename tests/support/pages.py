"""A component's history for the page tests: revisions of 'builder' measured at two parameter
sets, ingested and judged; and what the tests read back from a page."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
from redline.recording import RecordingWriter
from redline.server.db import session_factory
from redline.server.models import DetectionConfigRow
from redline.server.schemas.components import ComponentCreate
from redline.server.services.components import create_component

from tests.support.history import add_executions, ingest_and_detect


def two_parameter_sets(
    path: Path, run: dict[str, str], counters: dict[str, np.ndarray], case: str = "build"
) -> Path:
    """A recording of ``case`` at legs 2 and 8 (twice the counters' values at 8), with the
    component's output (markup in it, to be shown as text)."""
    with RecordingWriter(path) as writer:
        writer.metadata("redline.run", run)
        t_ns = 1_000_000_000
        for legs in (2, 8):
            params = {"legs": legs}
            writer.marker("begin", case, "steady", params, warmup=False, t_ns=t_ns)
            for index in range(len(counters["cpu"])):
                t_ns += 10_000_000
                sample = {
                    name: float(values[index]) * legs / 2 for name, values in counters.items()
                }
                writer.counters("builder", 4242, sample, t_ns)
            t_ns += 10_000_000
            writer.marker("end", case, "steady", params, warmup=False, t_ns=t_ns)
        writer.log("builder", b"builder ready\n<script>alert('from the log')</script>\n")
    return path


def history(
    database_url: str, tmp_path: Path, cpus: list[float], start: int = 1, case: str = "build"
) -> None:
    """Revisions r<start>.. of 'builder' with cpu and rss at legs 2 and 8, ingested and judged
    (by KS alone: one execution each)."""
    rng = np.random.default_rng(start)
    with session_factory(database_url)() as session:
        if start == 1:
            component = create_component(session, ComponentCreate(name="builder"))
            session.add(DetectionConfigRow(component_id=component.id, config={"methods": ["ks"]}))
            session.commit()
        executions = []
        for number, cpu in enumerate(cpus, start=start):
            counters = {"cpu": rng.normal(cpu, cpu / 20, 60), "rss": rng.normal(1e6, 1e3, 60)}
            executions += add_executions(
                session,
                tmp_path,
                "builder",
                f"r{number}",
                str(number),
                [counters],
                record=two_parameter_sets,
                case=case,
            )
    ingest_and_detect(database_url, executions)


def trend_data(page: str) -> dict:
    match = re.search(r'<script type="application/json" id="trend-data">(.*?)</script>', page, re.S)
    assert match, "the page carries its trend data"
    return json.loads(match.group(1))


def form_token(page: str) -> str:
    match = re.search(r'name="csrf" value="([^"]+)"', page)
    assert match, "a signed-in page carries its form token"
    return match.group(1)
