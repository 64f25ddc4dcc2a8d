"""Alerts: subscriptions and their filters, the delivery log, a component's commit-status target,
and the CI verdict of a revision."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal
from urllib.parse import urlsplit

from pydantic import (
    AfterValidator,
    BaseModel,
    Field,
    ValidationInfo,
    field_validator,
)
from redline.server.core.targets import refused_address
from redline.server.schemas.common import RequestBody
from redline.server.schemas.fields import Line, name_characters, printable


def email_address(value: str) -> str:
    """``value`` if it is one e-mail address, name@example.org ("" passes: none given)."""
    if not value:
        return value
    printable(value)
    for position, char in enumerate(value):
        if char in '<>,;"':
            raise ValueError(
                f"must be one address, as name@example.org: {char!r} at position {position}"
            )
    local, _, domain = value.rpartition("@")
    if not local or "@" in local or "." not in domain.strip("."):
        raise ValueError("must be one address, as name@example.org")
    return value


EmailAddress = Annotated[str, Field(max_length=320), AfterValidator(email_address)]


def http_url(value: str) -> str:
    """``value`` if it is an http(s) URL with a host ("" passes: none given), with no space or
    control character in it (httpx refuses to send those: each delivery would fail), and no
    user or password in it (a probe's showed in the settings page and the API's answers)."""
    if not value:
        return value
    printable(value)
    parts = urlsplit(value)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ValueError("must be an http:// or https:// URL with a host")
    if parts.username is not None or parts.password is not None:
        # it would be shown in the pages and the API's answers, and logged by proxies
        raise ValueError(
            "must not carry a user or password (user:password@): give the subscription a "
            "'secret' (it signs each body) or the commit status a 'token' instead"
        )
    refused = refused_address(parts.hostname)
    if refused is not None:
        raise ValueError(f"must not point at this host: {refused}")
    return value


HttpUrl = Annotated[str, Field(max_length=2000), AfterValidator(http_url)]


class SubscriptionFilters(RequestBody):
    counters: list[Line] | None = Field(
        default=None,
        max_length=100,
        description="counters or driver metrics to hear about (e.g. cpu, rss, rtt_p90); empty: all",
    )
    direction: Literal["regression", "improvement", "any"] | None = Field(
        default=None, description="changes for the worse, for the better, or both"
    )
    min_effect: float | None = Field(
        default=None,
        ge=0,
        le=100,
        allow_inf_nan=False,
        description="smallest relative effect told, a fraction (0.05: 5 %; 5: 500 %); the "
        "settings page takes it in percent",
    )
    confirmed_only: bool | None = Field(
        default=None,
        description="tell a regression once it is confirmed (imported results, which no agent "
        "can re-run, are told when flagged)",
    )
    delivery: Literal["immediate", "digest"] | None = Field(
        default=None, description="a message per alert, or one a day"
    )


class SubscriptionCreate(SubscriptionFilters):
    kind: Literal["email", "webhook"]
    address: EmailAddress = ""
    url: HttpUrl = ""
    secret: str = Field(default="", max_length=500, description="signs webhook bodies")
    format: Literal["redline", "slack"] = "redline"


class SubscriptionUpdate(SubscriptionFilters):
    """What PATCH may change: the filters, the target, a new secret. A field left out is
    kept; one given as null is refused (it was silently kept)."""

    address: EmailAddress | None = None
    url: HttpUrl | None = None
    secret: str | None = Field(default=None, max_length=500)
    format: Literal["redline", "slack"] | None = None

    @field_validator("*", mode="before")
    @classmethod
    def _not_null(cls, value: object, info: ValidationInfo) -> object:
        if value is None:
            keep = "leave it out to keep it"
            if info.field_name == "counters":
                keep += ", or give [] for every counter"
            raise ValueError(f"null changes nothing: {keep}")
        return value


class SubscriptionOut(BaseModel):
    id: int
    component: str | None = Field(description="None: every component")
    kind: str
    address: str
    url: str
    format: str
    has_secret: bool = Field(description="the secret is never shown again")
    counters: list[str]
    direction: str
    min_effect: float
    confirmed_only: bool
    delivery: str
    created: datetime


class DeliveryOut(BaseModel):
    id: int
    uid: str = Field(description="sent as X-Redline-Delivery, and in the mail's Message-ID")
    subscription: int | None
    kind: str
    event: str
    state: Literal["pending", "sending", "delivered", "failed", "superseded"]
    attempts: int
    last_error: str
    next_try: datetime | None = Field(description="when it is tried again (pending only)")
    created: datetime
    delivered: datetime | None


class CommitStatusTarget(RequestBody):
    provider: Literal["github", "gitlab"]
    api_url: HttpUrl = Field(
        description="https://api.github.com, or https://gitlab.example.com/api/v4"
    )
    repository: str = Field(
        min_length=1,
        max_length=300,
        description="owner/name on GitHub; the project's id or path on GitLab",
    )
    token: Annotated[str, AfterValidator(printable)] = Field(
        min_length=1, max_length=500, description="stored, never shown again"
    )

    @field_validator("repository")
    @classmethod
    def _a_repository_of_the_provider(cls, value: str, info: ValidationInfo) -> str:
        """The repository as the provider's API addresses it, never another of its paths
        (``../../orgs/x``): parts of letters, digits, '.', '_', '-'; owner/name on GitHub."""
        name_characters(value, also="/")
        parts = value.split("/")
        for part in parts:
            if part in ("", ".", ".."):
                raise ValueError(f"{part!r} is not allowed between '/'s: name each part")
        if info.data.get("provider") == "github" and len(parts) != 2:
            raise ValueError("on GitHub, owner/name (one '/')")
        return value


class CommitStatusOut(BaseModel):
    provider: str
    api_url: str
    repository: str
    has_token: bool


class CaseVerdict(BaseModel):
    case: str
    phase: str
    parameters: dict[str, Any] = Field(
        description="the parameter set, an object as everywhere else (the JUnit testcase's "
        "name holds it as canonical JSON text)"
    )
    state: Literal["passed", "failed", "skipped", "undecided"] = Field(
        description="skipped: no verdict yet (a history too short); undecided: none because "
        "the host was busy in every run of it or of its baseline, even after a fresh run, or "
        "because the method failed"
    )
    changes: list[dict] = Field(default_factory=list)
    reason: str = ""


class OpenRegression(BaseModel):
    id: int
    good_revision: str = Field(description="the newest revision before the change")
    bad_revision: str = Field(description="the newest revision showing it")
    confirmation: Literal["suspected", "confirmed"]
    state: str = Field(description="its triage state: new, acknowledged or confirmed")
    largest: str = Field(description="its largest change, in words")
    changed_back: str = Field(
        default="",
        description="where a revision since, up to this one, was flagged changing one of its "
        "series the other way (a revert, a fix), in words; empty otherwise: triage it fixed "
        "once the change back holds",
    )
    page: str


class CiVerdict(BaseModel):
    component: str
    revision: str
    state: Literal["pending", "done", "failed"] = Field(
        description="pending while jobs, analysis or confirmation runs are under way; failed: "
        "its jobs failed or were cancelled"
    )
    waiting_for: str = Field(default="", description="what a pending verdict waits for")
    reason: str = Field(default="", description="why a failed one failed (its jobs' reasons)")
    regressions: int = Field(description="changes for the worse, not dropped by confirmation")
    improvements: int
    skipped: int = Field(description="test cases without a verdict (not enough data)")
    undecided: int = Field(
        default=0,
        description="test cases without a verdict because the host was busy or a method failed",
    )
    cases: list[CaseVerdict]
    page: str = Field(description="the revision's page")
    open_before: list[OpenRegression] = Field(
        default_factory=list,
        description="regressions of the component still open (suspected or confirmed, not "
        "triaged as fixed, ignored or a false positive) whose change shows before this "
        "revision, newest first: the revision carries them unless it undid them. They do not "
        "count in its own verdict",
    )
    open_before_total: int = Field(default=0, description="how many there are in all")
    junit: str | None = Field(
        default=None,
        description="the verdict as JUnit XML, as `.../junit` gives it, when asked for with "
        "`junit` (what a failure is): one answer, so the XML and this verdict are of one state",
    )
