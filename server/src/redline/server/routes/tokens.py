"""/api/v1/tokens: admins issue, list and revoke API tokens."""

from __future__ import annotations

from fastapi import APIRouter, Depends, status
from redline.server.api.deps import SessionDep, require
from redline.server.core.bodies import JsonRoute
from redline.server.schemas.common import problems
from redline.server.schemas.tokens import TokenCreate, TokenCreated, TokenOut
from redline.server.services import tokens

router = APIRouter(
    prefix="/api/v1/tokens",
    tags=["tokens"],
    dependencies=[Depends(require("admin"))],
    route_class=JsonRoute,
)
PROBLEMS = problems(400, 404, 409)


@router.post("", status_code=status.HTTP_201_CREATED, responses=PROBLEMS)
def create_token(data: TokenCreate, session: SessionDep) -> TokenCreated:
    """A new token; its secret is in this answer only (the server keeps a hash)."""
    token, secret = tokens.issue_token(
        session, data.name, data.scopes, data.host, data.labels, data.components
    )
    return TokenCreated(**TokenOut.model_validate(token).model_dump(), token=secret)


@router.get("")
def list_tokens(session: SessionDep) -> list[TokenOut]:
    """Every token, revoked ones included, with when it was last used."""
    return [TokenOut.model_validate(token) for token in tokens.list_tokens(session)]


@router.delete("/{name_or_id}", responses=PROBLEMS)
def revoke_token(name_or_id: str, session: SessionDep) -> list[TokenOut]:
    """Revoke the token with this id, or the live token(s) with this name."""
    return [TokenOut.model_validate(token) for token in tokens.revoke_token(session, name_or_id)]
