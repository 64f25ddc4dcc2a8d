"""The host fingerprint recorded with every run (``redline.host`` metadata)."""

from __future__ import annotations

import os
import platform
import socket
from pathlib import Path

from redline.agent.governor import current_governors


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _memory_bytes() -> int:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError):
        return 0


def host_fingerprint(governor_state: str) -> dict[str, str]:
    """CPU model, cores, memory, kernel, hostname, Python, load before the run, governor state."""
    load = os.getloadavg()
    governors = current_governors()
    return {
        "hostname": socket.gethostname(),
        "cpu_model": _cpu_model(),
        "cpu_cores": str(os.cpu_count() or 0),
        "cpu_affinity": str(len(os.sched_getaffinity(0))),
        "memory_bytes": str(_memory_bytes()),
        "kernel": platform.release(),
        "os": platform.platform(),
        "python": platform.python_version(),
        "load_1m": f"{load[0]:.2f}",
        "load_5m": f"{load[1]:.2f}",
        "load_15m": f"{load[2]:.2f}",
        "governor_state": governor_state,
        "governors": ",".join(sorted(set(governors.values()))) or "none",
    }
