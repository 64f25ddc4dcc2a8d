"""What the service's detection and `redline compare` share: which series are judged, and how.

A series of the host-wide process (CPU shares, steal, load of the machine) is the context of a
run, not behaviour of the component: it is charted but never judged. A judged series goes through
the two-sample KS test with the counter's absolute floor (`redline.detect.floors`) on top of the
relative one, so both paths flag exactly the same changes.
"""

from __future__ import annotations

import numpy as np
from redline.detect.floors import absolute_floor
from redline.detect.ks import KsResult, ks
from redline.recording.format import HOST_PROCESS


def is_judged(process: str) -> bool:
    """False for the host-wide series, which describe the machine during the run."""
    return process != HOST_PROCESS


def judge(counter: str, baseline: np.ndarray, candidate: np.ndarray) -> KsResult:
    """KS on one series' pooled samples, with the counter's absolute effect floor."""
    return ks(baseline, candidate, min_change=absolute_floor(counter))
