"""Errors a user can cause; the app turns each into its HTTP status with the message as detail."""

from __future__ import annotations


class ServiceError(Exception):
    status_code = 400

    def __init__(self, detail: str) -> None:
        super().__init__(detail)
        self.detail = detail


class BadRequest(ServiceError):
    status_code = 400


class Forbidden(ServiceError):
    status_code = 403


class Unprocessable(ServiceError):
    """A well-formed request whose value cannot be used (422, as for a schema error)."""

    status_code = 422


class Unstorable(Unprocessable, ValueError):
    """A series name Postgres would refuse (an index row over 2,704 bytes, a NUL) or that would
    break every line naming it; a ValueError too, so a recording naming one fails its job
    instead of being retried."""


class NotFound(ServiceError):
    status_code = 404


class Conflict(ServiceError):
    status_code = 409


class TooLarge(ServiceError):
    status_code = 413
