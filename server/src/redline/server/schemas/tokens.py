"""API tokens: what an admin asks for, and what is shown (the secret once)."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated

from pydantic import AfterValidator, BaseModel, ConfigDict, Field
from redline.server.schemas.common import RequestBody
from redline.server.schemas.fields import Word, path_segment

#: the longest token name: a session it opens is someone's "token <name>", at most 200
#: characters (a review: a name of 195-200 was issued, and signing in with it failed)
TOKEN_NAME_CHARS = 200 - len("token ")


class TokenCreate(RequestBody):
    # one path segment of one line, refused by name (422) as every name is (a trial's "\x07")
    name: Annotated[str, AfterValidator(path_segment)] = Field(
        min_length=1, max_length=TOKEN_NAME_CHARS
    )
    scopes: list[str] = Field(min_length=1, description="ci, triage, agent, read, admin")
    host: str | None = Field(
        default=None, max_length=200, description="for an agent token: the one host it may act as"
    )
    labels: list[Word] = Field(
        default_factory=list,
        max_length=100,
        description="for an agent token: the labels its host may register with",
    )
    components: list[str] = Field(
        default_factory=list,
        max_length=1000,
        description="for a ci, triage or agent token: the only components it acts on (reports "
        "revisions of, triages, runs the jobs and reports run-time alerts of); none: every one",
    )


class TokenOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    name: str
    scopes: list[str]
    host: str | None
    labels: list[str]
    components: list[str]
    created: datetime
    last_used: datetime | None
    revoked: bool


class TokenCreated(TokenOut):
    token: str = Field(description="the secret; shown once, stored only as a hash")
