"""Structured logs: one JSON object per line when ``REDLINE_LOG_JSON=true``; secrets redacted."""

from __future__ import annotations

import json
import logging
import re
from datetime import UTC, datetime

from redline.server.core.security import TOKEN_PREFIX

#: a credential in a URL's query (``?token=...``, ``&client_secret=...``: any name ending in
#: one of these words), and a Redline token wherever it appears
_CREDENTIAL = re.compile(
    r"(?P<name>[?&][\w.-]*?(?:token|key|secret|password|passwd|signature|sig|auth|credentials?)=)"
    r"[^&\s\"']*",
    re.IGNORECASE,
)
_TOKEN = re.compile(r"(?<![A-Za-z0-9_])" + re.escape(TOKEN_PREFIX) + r"[A-Za-z0-9_-]{20,}")
REDACTED = "***"


def redact(text: str) -> str:
    """``text`` with query-string credentials and Redline tokens replaced by ``***``."""
    return _TOKEN.sub(REDACTED, _CREDENTIAL.sub(rf"\g<name>{REDACTED}", text))


class RedactSecrets(logging.Filter):
    """Rewrites each record's message with `redact` (an access log line quotes the whole URL,
    query string included, and the UI takes a read token as ``?token=``)."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        cleaned = redact(message)
        if cleaned != message:
            record.msg, record.args = cleaned, None
        return True


_STANDARD = set(vars(logging.LogRecord("", 0, "", 0, "", None, None))) | {"message", "asctime"}


class JsonFormatter(logging.Formatter):
    """time, level, logger, message, exception, and any ``extra=`` fields of the call."""

    def format(self, record: logging.LogRecord) -> str:
        entry = {
            "time": datetime.fromtimestamp(record.created, UTC).isoformat(timespec="milliseconds"),
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
        }
        entry.update({k: v for k, v in vars(record).items() if k not in _STANDARD})
        if record.exc_info:
            entry["exception"] = self.formatException(record.exc_info)
        return json.dumps(entry, default=str)


#: the loggers of the HTTP server, which log the requests' addresses
URL_LOGGERS = ("uvicorn", "uvicorn.access", "uvicorn.error")


def configure(json_lines: bool, level: int = logging.INFO) -> None:
    """Log to stderr, as JSON lines or as text, with secrets redacted."""
    handler = logging.StreamHandler()
    handler.addFilter(RedactSecrets())
    handler.setFormatter(
        JsonFormatter()
        if json_lines
        else logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s")
    )
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level)
    # a server's loggers that uvicorn's own logging configuration (applied by any uvicorn run in
    # this process) gives handlers of their own: their lines, which carry the requests' URLs,
    # must pass the redacting handler above like every other
    for name in URL_LOGGERS:
        logger = logging.getLogger(name)
        logger.handlers.clear()
        logger.propagate = True
        logger.disabled = False
