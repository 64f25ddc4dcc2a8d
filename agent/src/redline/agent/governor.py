"""Pinning the CPU frequency governor to ``performance`` for a run, and restoring it after.

States: ``pinned`` (set, restored on exit), ``unavailable`` (no cpufreq in /sys, as on most VMs),
``denied`` (present but not writable, e.g. not root or /sys mounted read-only). The run carries on
in every state; the state goes into the host fingerprint so analyses can tell runs apart.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

CPU_ROOT = Path("/sys/devices/system/cpu")
TARGET = "performance"


def governor_files(root: Path = CPU_ROOT) -> list[Path]:
    """The scaling_governor file of every CPU that has one."""
    return sorted(root.glob("cpu[0-9]*/cpufreq/scaling_governor"))


def current_governors(root: Path = CPU_ROOT) -> dict[str, str]:
    """CPU name → governor, for the fingerprint (empty when unavailable)."""
    found: dict[str, str] = {}
    for path in governor_files(root):
        try:
            found[path.parent.parent.name] = path.read_text().strip()
        except OSError:
            continue
    return found


@contextmanager
def pinned_governor(root: Path = CPU_ROOT) -> Iterator[str]:
    """Pin every CPU to ``performance`` while the block runs; yields the state reached."""
    files = governor_files(root)
    if not files:
        yield "unavailable"
        return
    saved: dict[Path, str] = {}
    state = "pinned"
    try:
        for path in files:
            previous = path.read_text().strip()
            if previous != TARGET:
                path.write_text(TARGET)
                saved[path] = previous
    except OSError:
        state = "denied"
    try:
        yield state
    finally:
        for path, previous in saved.items():
            with contextlib.suppress(OSError):  # best effort; the state was reported
                path.write_text(previous)
