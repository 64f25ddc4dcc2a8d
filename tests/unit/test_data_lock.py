"""`redline up` holds its data folder: a second one on the same folder is refused before it
starts anything (a trial saw it share and then stop the first one's embedded Redis)."""

from __future__ import annotations

import os

import pytest
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
