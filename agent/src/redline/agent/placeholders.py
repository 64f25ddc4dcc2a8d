"""Placeholders in a suite's commands: ``{zenoh_config}`` and its kind, replaced when a run starts.

Whole known names in single braces are replaced; ``{{name}}`` is a literal ``{name}``; other
braces pass unchanged (JSON arguments such as ``'{"a": 1}'``, the shell's ``${NAME}``).
"""

from __future__ import annotations

import re
from collections.abc import Mapping

#: The placeholders a command may hold, and what each stands for.
PLACEHOLDERS = {"zenoh_config": "the path of the run's zenoh configuration file"}
# {{name}} (a literal {name}) or {name} not preceded by '$' (that is the shell's ${NAME})
_PLACEHOLDER = re.compile(r"\{\{([A-Za-z_]\w*)\}\}|(?<!\$)\{([A-Za-z_]\w*)\}")


def unknown_placeholders(command: tuple[str, ...]) -> list[str]:
    """The ``{name}``s in a command that are not known placeholders."""
    return [
        m[2]
        for arg in command
        for m in _PLACEHOLDER.finditer(arg)
        if m[2] and m[2] not in PLACEHOLDERS
    ]


def substitute(command: tuple[str, ...], values: Mapping[str, str]) -> tuple[str, ...]:
    """``command`` with its placeholders replaced by ``values`` and ``{{name}}`` unescaped."""
    return tuple(
        _PLACEHOLDER.sub(lambda m: f"{{{m[1]}}}" if m[1] else values[m[2]], arg) for arg in command
    )
