"""Two transactions interleaved on the real database: the first held just before its commit, the
second run until it waits on a lock the first holds, to show what taking turns decides."""

from __future__ import annotations

import threading
from collections.abc import Callable

from redline.server.db import session_factory
from sqlalchemy import event, text
from sqlalchemy.orm import Session


def _pause_before_commit(session: Session, reached: threading.Event, go: threading.Event) -> None:
    def hold(held: Session) -> None:
        held.flush()  # its writes made, its locks held: only the commit is left
        reached.set()
        assert go.wait(30), "never released"

    event.listen(session, "before_commit", hold)


def waiting_on_a_lock(database_url: str) -> bool:
    with session_factory(database_url)() as session:
        return bool(
            session.scalar(
                text(
                    "SELECT count(*) FROM pg_stat_activity WHERE wait_event_type = 'Lock' "
                    "AND datname = current_database()"
                )
            )
        )


def interleave(
    database_url: str, first: Callable[[Session], object], second: Callable[[Session], object]
) -> list[object]:
    """``first`` runs up to its commit; ``second`` then runs until it waits on a lock that
    ``first`` holds (or ends); then ``first`` commits and both finish. What each returned or
    raised, in that order: the interleaving that turns select-then-insert into a duplicate."""
    results: list[object] = [None, None]
    reached, go = threading.Event(), threading.Event()

    def run(index: int, work: Callable[[Session], object], hold: bool) -> None:
        with session_factory(database_url)() as session:
            if hold:
                _pause_before_commit(session, reached, go)
            try:
                results[index] = work(session)
            except Exception as exc:  # the duplicate key error is the bug being shown
                results[index] = exc

    one = threading.Thread(target=run, args=(0, first, True))
    one.start()
    assert reached.wait(30), "the first transaction never reached its commit"
    two = threading.Thread(target=run, args=(1, second, False))
    two.start()
    for _ in range(300):
        if not two.is_alive() or waiting_on_a_lock(database_url):
            break
        two.join(0.05)
    go.set()
    one.join(30)
    two.join(30)
    return results
