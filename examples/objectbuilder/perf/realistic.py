"""The realistic replay the resource models are evaluated on (docs/prediction.md): leg detections
as a person-tracking robot sees them, after the paper's data set (Wienke & Wrede, Section 6.2).

Leg counts per message have a median of 6 with rare peaks near 20 (people gathering, then
leaving), at 30 messages/s; robot poses at 10/s; 180 s. Generated once, with a fixed seed, into
``data/realistic.mcap`` (zstd-compressed chunks, ~0.2 MB), which is committed:

    .venv/bin/python examples/objectbuilder/perf/realistic.py

The leg message layout is the test's own (`test_objectbuilder.LegMessage`), so the replay sends
what the performance tests send, only with another distribution of counts.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
from redline.recording import RecordingWriter

HERE = Path(__file__).parent
OUT = HERE / "data" / "realistic.mcap"
SECONDS, LEG_HZ, POSE_HZ, SEED = 180, 30, 10, 20261123
NS = 1_000_000_000


def leg_counts(rng: np.random.Generator, steps: int) -> np.ndarray:
    """A slowly wandering crowd around 6 legs, and a few gatherings that bring it near 20."""
    level = np.empty(steps)
    value = 5.6
    for index in range(steps):
        value += 0.02 * (5.6 - value) + rng.normal(0, 0.25)
        level[index] = value
    for start in rng.choice(steps - 200, size=4, replace=False):  # rare peaks of a few seconds
        length = int(rng.integers(60, 150))
        bump = 13 * np.sin(np.linspace(0, math.pi, length))
        level[start : start + length] += bump[: steps - start]
    return np.clip(np.rint(level + rng.normal(0, 0.7, steps)), 1, 22).astype(int)


def legs_payload(count: int, stamp: int) -> bytes:
    legs = []
    for index in range(count):
        angle = (index // 2) * 2 * math.pi / max(1, count // 2)
        offset = 0.3 * (index % 2)
        legs.append({"x": 2.0 * math.cos(angle) + offset, "y": 2.0 * math.sin(angle)})
    return json.dumps({"stamp": stamp, "legs": legs}).encode()


def main() -> int:
    rng = np.random.default_rng(SEED)
    counts = leg_counts(rng, SECONDS * LEG_HZ)
    OUT.parent.mkdir(exist_ok=True)
    with RecordingWriter(OUT) as writer:
        writer.metadata("redline.replay", {"generator": "realistic.py", "seed": str(SEED)})
        for index, count in enumerate(counts):
            t = NS + index * NS // LEG_HZ
            writer.write("objectbuilder/legs", legs_payload(int(count), t), t_ns=t)
            if index % (LEG_HZ // POSE_HZ) == 0:
                pose = {"x": 1.0 + 0.01 * index, "y": 0.5, "theta": 0.1}
                writer.write("objectbuilder/pose", json.dumps(pose).encode(), t_ns=t + 1000)
    print(
        f"{OUT}: {len(counts)} leg messages, median {np.median(counts):.0f} legs, "
        f"max {counts.max()}, {np.mean(counts >= 15):.1%} of them with 15 or more"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
