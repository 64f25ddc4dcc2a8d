"""A job's run in a process of its own, which ends with it.

The test driver runs in the process that calls `run_suite`, and what a run leaves behind in
that process stays for the process's lifetime. Zenoh keeps every shared-memory segment a
process has read from mapped (and locked) until that process exits (eclipse-zenoh/zenoh#2787):
a driver that heard a component's payloads of 3 KiB or more kept that component's pool, and the
agent daemon, which lived on from job to job, grew by about 50 MB a job (measured on a trial's
component, 2026-11-27) until, under a lock limit, samples would be dropped without a word. Each
job's run therefore happens in a child process (spawned, in a session of its own, so that a
terminal's Ctrl-C reaches the agent, which decides), and everything it mapped goes with it.

The agent's signals keep their meaning: the first lets the run finish; the second (or the end
of the grace period) raises in the agent while it waits, which sends the child SIGTERM, and the
child's runner stops every process and finishes the recording as ``terminated``, as a run in
the agent's own process did.

A child killed outright (SIGKILL: out of memory, an operator) cannot stop what it started: the
component, in a session of its own, ran on under init beside the agent's next job. The agent
is therefore the reaper of its descendants' orphans (`adopt_orphans`, PR_SET_CHILD_SUBREAPER):
what the run left is adopted by the agent, which ends it (its process group, SIGTERM, then
SIGKILL) and reaps it once the child is gone.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import time
import traceback
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from redline.agent.runner import RunResult, run_suite

#: how long a child told to stop may take to stop the run's processes and finish its recording,
#: and how long one that answered may take to exit
STOP_WAIT_S = 60.0
#: how long an orphan of the run has to end on SIGTERM before SIGKILL
ORPHAN_WAIT_S = 5.0
PR_SET_PDEATHSIG = 1  # linux/prctl.h
PR_SET_CHILD_SUBREAPER = 36


def _prctl(option: int, value: int) -> bool:
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return int(libc.prctl(option, value, 0, 0, 0)) == 0
    except (OSError, AttributeError):  # not Linux
        return False


def adopt_orphans() -> bool:
    """Make this process (the agent) the parent of its descendants' orphans, so that a run
    whose process was killed leaves nothing behind it (`run_isolated`); False where the system
    cannot (not Linux): such orphans then run on under init, as before."""
    return _prctl(PR_SET_CHILD_SUBREAPER, 1)


def _children() -> set[int]:
    """This process's children (adopted orphans included), from /proc."""
    found: set[int] = set()
    for task in Path("/proc/self/task").glob("*"):
        try:
            found.update(int(pid) for pid in (task / "children").read_text().split())
        except (OSError, ValueError):
            continue
    return found


def _signal_group(pid: int, sig: int) -> None:
    """``sig`` to the process group of ``pid`` (a component's own helpers go with it), or to
    ``pid`` alone when that group is this process's own."""
    try:
        group = os.getpgid(pid)
        if group == os.getpgrp():
            os.kill(pid, sig)
        else:
            os.killpg(group, sig)
    except (ProcessLookupError, PermissionError):
        return  # ended meanwhile: reaped by the caller


def _end_orphans(before: set[int]) -> list[int]:
    """End and reap the children this process has gained since ``before`` (the orphans a
    killed run left to it): each one's process group SIGTERM, then SIGKILL after
    `ORPHAN_WAIT_S`. Returns their pids (an orphan's own children, adopted as it ends, too)."""
    ended: list[int] = []
    for sig in (signal.SIGTERM, signal.SIGKILL):
        orphans = _children() - before
        for pid in orphans:
            _signal_group(pid, sig)
        deadline = time.monotonic() + ORPHAN_WAIT_S
        while orphans and time.monotonic() < deadline:
            for pid in list(orphans):
                try:
                    done = os.waitpid(pid, os.WNOHANG)[0] == pid
                except ChildProcessError:  # reaped elsewhere
                    done = True
                if done:
                    orphans.discard(pid)
                    ended.append(pid)
            orphans |= _children() - before - set(ended)  # adopted as their parents ended
            time.sleep(0.05)
        if not orphans:
            break
    return ended


class ChildFailed(RuntimeError):
    """The child's run raised: the message names the exception as the agent's own run did;
    ``trace``: the child's traceback ("" when it died without a word), for the agent's log."""

    def __init__(self, message: str, trace: str = "") -> None:
        super().__init__(message)
        self.trace = trace


def _die_with_parent() -> None:
    """SIGTERM to this process when the agent dies (Linux): its runner then stops the run's
    processes, instead of a suite running on unsupervised beside the agent's next one."""
    if not _prctl(PR_SET_PDEATHSIG, signal.SIGTERM):
        return  # not Linux: the agent's own stop still ends the run
    if os.getppid() == 1:  # the agent died before the request was made
        os.kill(os.getpid(), signal.SIGTERM)


def _child(
    conn: Any,
    suite_path: Path,
    out: Path,
    meta: dict[str, str],
    only: list[str],
    sets: dict[str, list[str]] | None = None,
    alone: bool = False,
) -> None:
    os.setsid()  # a terminal's signals reach the agent, not the run behind its back
    _die_with_parent()
    try:
        result = run_suite(
            suite_path, out, run_metadata=meta, only=only, parameter_sets=sets, sets_alone=alone
        )
    except Exception as exc:  # the agent fails the job with it, and logs where it was raised
        conn.send(("error", f"{type(exc).__name__}: {exc}", traceback.format_exc()))
    except BaseException as exc:  # stopped by the agent: the recording says so
        conn.send(("stopped", f"{type(exc).__name__}: {exc}", ""))
    else:
        conn.send(("done", result, ""))
    finally:
        conn.close()


def run_isolated(
    suite_path: Path,
    out: Path,
    run_metadata: dict[str, str],
    only: Sequence[str] = (),
    sets: Mapping[str, Sequence[str]] | None = None,
    alone: bool = False,
) -> RunResult:
    """`run_suite` in a child process (``only`` its cases, ``sets`` the parameter sets it ends
    after, or with ``alone`` the only ones it runs); raises `ChildFailed` with the run's
    error."""
    context = multiprocessing.get_context("spawn")
    receive, send = context.Pipe(duplex=False)
    chosen = {case: list(idents) for case, idents in (sets or {}).items()}
    child = context.Process(
        target=_child,
        args=(send, suite_path, out, run_metadata, list(only), chosen, alone),
        name="redline-run",
    )
    child.start()
    # after the start: spawning starts multiprocessing's resource tracker, a child of ours that
    # must outlive the run (killed, it was started again, and killed again, job after job)
    before = _children()
    send.close()
    try:
        answer = receive.recv()  # EOFError when the child died without a word
    except EOFError:
        left = _reap(child, before, stop=False)
        ended = f"; {len(left)} process(es) it had started ended with it" if left else ""
        raise ChildFailed(
            f"the run's process ended without a result (exit {child.exitcode}){ended}"
        ) from None
    except BaseException:  # the agent is stopping: the run ends, its processes with it
        _reap(child, before, stop=True)
        raise
    finally:
        receive.close()
    _reap(child, before, stop=False)
    state, value, trace = answer
    if state != "done":
        raise ChildFailed(value, trace)
    result: RunResult = value
    return result


def _reap(child: Any, before: set[int], stop: bool) -> list[int]:
    """Wait for the child to exit (``stop``: after SIGTERM, which its runner turns into a
    clean stop), at most `STOP_WAIT_S`; then kill it, so the agent never waits for ever. Then
    end what it left (`_end_orphans`: nothing, unless it was killed); returns their pids."""
    if stop and child.is_alive() and child.pid is not None:
        os.kill(child.pid, signal.SIGTERM)
    child.join(STOP_WAIT_S)
    if child.is_alive():
        child.kill()
        child.join(STOP_WAIT_S)
    return _end_orphans(before | {child.pid or 0})
