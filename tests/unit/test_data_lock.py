"""`redline up` holds its data folder and its port: a second one on the same folder, or a port
already taken, is refused before it starts anything (a trial saw it share and then stop the first
one's embedded Redis); the admin commands find its services through the data folder."""

from __future__ import annotations

import os
import signal
import socket

import pytest
from redline.commands.embedded import read_services, write_services
from redline.commands.service import needs_database
from redline.commands.stack import Stack, StackError, lock_data


def test_a_second_holder_of_the_data_folder_is_refused_naming_the_first(tmp_path) -> None:
    held = lock_data(tmp_path)
    with pytest.raises(StackError, match=rf"in use by another `redline up` \(pid {os.getpid()}\)"):
        lock_data(tmp_path)
    held.close()
    lock_data(tmp_path).close()  # free again once the first is gone


def test_a_refused_stack_starts_nothing_and_leaves_the_first_alone(tmp_path) -> None:
    held = lock_data(tmp_path)
    second = Stack(tmp_path, port=1)
    with pytest.raises(StackError, match="in use"):
        second.start()  # refused before the database, Redis or any process is started
    assert second.children == [] and second.embedded is None
    second.stop()
    with pytest.raises(StackError):  # the first still holds it
        lock_data(tmp_path)
    held.close()


def test_a_taken_port_is_refused_before_anything_starts(tmp_path) -> None:
    """A trial waited 20 s for Postgres and migrations, then read a page of logs ending in
    "address already in use"."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        stack = Stack(tmp_path, port=port)
        with pytest.raises(StackError, match=rf"port {port} is taken .*--port"):
            stack.start()
        assert stack.children == [] and stack.embedded is None
        stack.stop()
        assert (tmp_path / "lock").exists()  # a folder it did not make keeps what it holds
        # one it made is not left behind (a trial found it, holding only the lock)
        new = Stack(tmp_path / "new" / "data", port=port)
        with pytest.raises(StackError, match=rf"port {port} is taken"):
            new.start()
        assert not (tmp_path / "new" / "data").exists()
        new.stop()


def test_the_admin_commands_find_the_database_of_the_redline_up_running_here(
    tmp_path, monkeypatch
) -> None:
    """The README's `redline user create` under the Quick start said: database "redline" does
    not exist (the embedded database is named only in the data folder)."""
    data = tmp_path / ".redline"
    data.mkdir()
    write_services(data, {"REDLINE_DATABASE_URL": "postgresql+psycopg://u@/redline?host=/s"})
    assert (data / "services.env").stat().st_mode & 0o777 == 0o600
    assert read_services(data) == {
        "REDLINE_DATABASE_URL": "postgresql+psycopg://u@/redline?host=/s"
    }
    monkeypatch.delenv("REDLINE_DATABASE_URL", raising=False)
    monkeypatch.chdir(tmp_path)
    seen = []
    needs_database(lambda: seen.append(os.environ["REDLINE_DATABASE_URL"]))()
    assert seen == ["postgresql+psycopg://u@/redline?host=/s"]
    # a configured database is the one used, whatever a data folder says
    monkeypatch.setenv("REDLINE_DATABASE_URL", "postgresql+psycopg://other/db")
    needs_database(lambda: seen.append(os.environ["REDLINE_DATABASE_URL"]))()
    assert seen[-1] == "postgresql+psycopg://other/db"


def test_a_refused_start_says_no_stopping(tmp_path) -> None:
    """A trial's refused second `redline up` said "stopping…" after its error."""
    import typer
    from redline.commands.up import _serve
    from rich.console import Console

    held = lock_data(tmp_path)
    console = Console(record=True, width=200)
    handlers = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        with pytest.raises(typer.Exit):
            _serve(console, tmp_path, port=1)
    finally:  # _serve takes Ctrl-C and SIGTERM for its own
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
    said = console.export_text()
    assert "in use by another `redline up`" in said and "stopping" not in said, said
    held.close()
