"""Signing in and out of the pages (``/signin``, ``/signout``): needs no read access.

The sign-in form carries a token of its own, kept in a cookie the form page sets
(`redline.server.services.signin.SIGNIN_COOKIE`): a sign-in posted without it, as another site
would post one to sign a browser in to the other site's account, is refused (403).
"""

from __future__ import annotations

from fastapi import Request, Response
from fastapi.responses import HTMLResponse, RedirectResponse
from redline.server.api.deps import SessionDep, SettingsDep
from redline.server.services import signin
from redline.server.services.errors import Forbidden
from redline.server.ui.pages import form_fields, page, page_router, problem, signed_in

router = page_router(read=False)


def _local(target: str) -> str:
    """Where to go after signing in: a path on this server only, never another host."""
    return target if target.startswith("/") and not target.startswith("//") else "/"


def _form(request: Request, target: str, message: str = "", status_code: int = 200) -> Response:
    """The sign-in page, with the browser's sign-in token in its form and in its cookie."""
    token = signin.signin_token(request.cookies.get(signin.SIGNIN_COOKIE))
    context = {"next": target, "message": message, "csrf": token}
    answer = page(request, "signin.html", context, status_code=status_code)
    answer.set_cookie(
        signin.SIGNIN_COOKIE,
        token,
        max_age=signin.SIGNIN_HOURS * 3600,
        path="/signin",
        httponly=True,
        samesite="strict",
        secure=request.url.scheme == "https",
    )
    return answer


@router.get("/signin", response_class=HTMLResponse)
def signinpage(request: Request, next: str = "/") -> Response:
    return _form(request, _local(next))


@router.post("/signin", response_class=HTMLResponse)
async def signin_form(request: Request, session: SessionDep, settings: SettingsDep) -> Response:
    form = await form_fields(request)
    target = _local(form.get("next", "/"))
    try:
        signin.check_signin_form(request.cookies.get(signin.SIGNIN_COOKIE), form.get("csrf", ""))
        opened = signin.sign_in(
            session,
            form.get("name", ""),
            form.get("password", ""),
            form.get("token", ""),
            pages_closed=settings.read_access == "token",
        )
    except Forbidden as exc:
        return _form(request, target, exc.detail, status_code=403)
    answer = RedirectResponse(target, status_code=303)
    answer.set_cookie(
        signin.SESSION_COOKIE,
        opened.secret,
        max_age=signin.SESSION_DAYS * 86400,
        httponly=True,
        samesite="strict",
        secure=request.url.scheme == "https",
    )
    return answer


@router.post("/signout", response_class=HTMLResponse)
async def signout_form(request: Request, session: SessionDep) -> Response:
    """Ends the session, when the form carries its token: another site's form, which cannot,
    is refused (403) and ends nothing, the cookie included. Not signed in, there is nothing
    to end."""
    form = await form_fields(request)
    row = signed_in(request)
    if row is not None:
        try:
            signin.check_form(row, str(form.get("csrf", "")))
        except Forbidden as exc:
            return problem(request, exc)
        signin.sign_out(session, request.cookies.get(signin.SESSION_COOKIE))
    answer = RedirectResponse("/", status_code=303)
    answer.delete_cookie(signin.SESSION_COOKIE)
    return answer
