"""Keyset paging for the lists that grow with the history (changes, detections, regressions).

A page ends where the next one starts: its last row's sort values, encoded as an opaque cursor
that the API hands out in the ``X-Next-Cursor`` header of a full page. Unlike an offset, a
cursor stays right while new rows arrive.
"""

from __future__ import annotations

import base64
import json
from typing import Any

from redline.server.services.errors import BadRequest
from sqlalchemy import ColumnElement, and_, literal, or_


def encode_cursor(*values: Any) -> str:
    raw = json.dumps(list(values), separators=(",", ":")).encode()
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def decode_cursor(cursor: str, *kinds: type) -> tuple[Any, ...]:
    """The values of a cursor made by `encode_cursor`, each checked against its kind; a
    `BadRequest` naming the cursor when it is not one."""
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4))
        values = json.loads(raw)
    except (ValueError, UnicodeDecodeError, RecursionError):  # '[' * 1200: an audit's 500
        values = None
    if (
        not isinstance(values, list)
        or len(values) != len(kinds)
        or not all(type(value) is kind for value, kind in zip(values, kinds, strict=True))
    ):
        given = f"{cursor[:80]!r}" + ("..." if len(cursor) > 80 else "")
        raise BadRequest(f"malformed cursor {given}; pass back an X-Next-Cursor")
    return tuple(values)


def after_newest_first(
    cursor: str | None, order_key: Any, flagged: Any, ident: Any
) -> ColumnElement[bool] | None:
    """Where the rows after ``cursor`` start, for lists ordered newest revision first, flagged
    first within a revision, then by id: ``(order_key DESC, flagged DESC, id ASC)``."""
    if not cursor:
        return None
    key, was_flagged, last = decode_cursor(cursor, str, bool, int)
    key, was = literal(key, order_key.type), literal(was_flagged, flagged.type)
    same_flag = and_(flagged == was, ident > last)
    return or_(order_key < key, and_(order_key == key, or_(flagged < was, same_flag)))
