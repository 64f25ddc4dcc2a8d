"""Repository URLs: the https, ssh and scp-like spellings of one repository compare equal."""

from __future__ import annotations

import re
from urllib.parse import urlsplit

_SCP_LIKE = re.compile(r"^(?:[\w.-]+@)?(?P<host>[\w.-]+):(?P<path>(?!//).+)$")


def repo_key(url: str) -> str:
    """A canonical ``host/owner/name`` for a repository URL, lower-cased, without ``.git``.

    ``https://github.com/Org/Repo.git``, ``git@github.com:org/repo`` and
    ``ssh://git@github.com:22/org/repo.git`` all give ``github.com/org/repo``. A local path
    (``/src/builder.git``) keeps its path. An empty URL gives ``""``, which matches nothing, and
    so does one no URL parser reads (``https://[x``: a review's forged webhook delivery made it
    a 500 before its signature was checked).
    """
    text = url.strip()
    if not text:
        return ""
    if "://" in text:
        try:
            parts = urlsplit(text)
            host = (parts.hostname or "") if parts.scheme != "file" else ""
        except ValueError:  # an unclosed '[' of an IPv6 host
            return ""
        path = parts.path
    elif (match := _SCP_LIKE.match(text)) and not text.startswith("/"):
        host, path = match["host"], match["path"]
    else:
        host, path = "", text
    path = path.strip("/")
    if path.endswith(".git"):
        path = path[: -len(".git")].rstrip("/")  # a work tree's own .git folder too
    return f"{host}/{path}".strip("/").lower() if host else "/" + path.lower()
