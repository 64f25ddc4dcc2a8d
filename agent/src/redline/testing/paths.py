"""Where an action sits in its phase's tree: the name its driver metrics are recorded under.

A path names the actions from the phase's root down, each by its class and, for an action with
a plain key expression, the key: ``Parallel/FixedRate/Publish(robot/cmd)``. Siblings with the
same name are numbered from the second on (``Query(robot/get)#2``), so two actions of one phase
never share a path, and a path stays the same from revision to revision while the tree does.
"""

from __future__ import annotations

from collections import Counter
from typing import Any


def label(action: Any) -> str:
    """An action's name in a path: its class, with its key expression when that is plain text."""
    key = getattr(action, "key", None)
    return f"{type(action).__name__}({key})" if isinstance(key, str) else type(action).__name__


def action_paths(root: Any) -> dict[int, str]:
    """Every action of the tree under ``root`` (by ``id``) with its path; an action that appears
    twice in the tree keeps the place where it is first met."""
    paths: dict[int, str] = {}

    def visit(action: Any, path: str) -> None:
        if id(action) in paths:
            return
        paths[id(action)] = path
        seen: Counter[str] = Counter()
        for child in action.children():
            name = label(child)
            seen[name] += 1
            visit(child, f"{path}/{name}" + (f"#{seen[name]}" if seen[name] > 1 else ""))

    visit(root, label(root))
    return paths
