"""Recordings of a leg-processing component (the paper's mock component, in miniature), written by
the real writer, and a small grid that fits in a fraction of a second."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from redline.predict.features import NS
from redline.predict.model import ResourceModel
from redline.recording import RecordingWriter

SMALL = ResourceModel(clusters=(2, 4), alphas=(1e-2, 1e-1), gammas=(1e-2, 1e-1), folds=3)


def record(
    path: Path,
    legs: list[int],
    seed: int = 0,
    traffic: bool = True,
    extra: str = "",
    base: float = 5.0,
) -> Path:
    """A recording as a run of a leg-processing component makes it: per segment a leg count,
    'legs' samples at 30 Hz whose size grows with it, 'persons' sent back, and the component's CPU
    growing with the square of the legs (as the paper's mock component's does); ``extra``: one
    more key, on which the component's CPU does not depend; ``base``: its CPU without legs."""
    rng = np.random.default_rng(seed)
    with RecordingWriter(path) as writer:
        writer.metadata("redline.run", {"component": "builder"})
        t = NS
        for count in legs:
            params = {"legs": count}
            writer.marker("begin", "legs", "steady", params, t_ns=t)
            writer.write_json(
                "@redline/driver/legs/steady",
                {"t_ns": t, "case": "legs", "phase": "steady", "params": params,
                 "action": "Publish", "key": "robot/legs", "published": 300},
            )  # fmt: skip
            for step in range(300):  # 10 s at 30 Hz
                now = t + step * NS // 30
                if traffic:
                    writer.write("robot/legs", b"x" * (16 * count), t_ns=now)
                    if step % 3 == 0:
                        writer.write("robot/persons", b"p" * (8 * count), t_ns=now + 1000)
                    if extra:  # a key training never saw
                        writer.write(extra, b"e", t_ns=now + 2000)
                if step % 3 == 0:
                    cpu = base + 0.4 * count**2 + rng.normal(0, 1.0)
                    writer.counters("builder", 7, {"cpu_percent": cpu, "rss_bytes": 1e8}, now)
            t += 10 * NS
            writer.marker("end", "legs", "steady", params, t_ns=t)
            t += NS // 10
    return path
