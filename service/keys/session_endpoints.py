"""HTTP routes of browser sessions: sign in with an API key (a cookie for the dashboard and report pages),
sign out."""

from __future__ import annotations

from datetime import timedelta

from fastapi import APIRouter, Request, Response

from service.deps import AnyKey, ContextDep
from service.errors import Unauthorized
from service.keys.endpoints import key_out
from service.keys.schemas import SessionOut
from service.keys.sessions import SESSION_COOKIE, close_session, open_session
from service.problems import problem_responses

__all__ = ["router"]

router = APIRouter(prefix="/v1/session", tags=["keys"])


@router.post("", response_model=SessionOut, responses=problem_responses(Unauthorized))
def sign_in(request: Request, response: Response, context: ContextDep, key: AnyKey) -> SessionOut:
    """Sign a browser in with the key sent as bearer: sets an HttpOnly, SameSite=Strict session cookie that
    reads with the key's scopes until ``expires_at``; API clients keep sending the key."""
    if request.headers.get("authorization") is None:
        raise Unauthorized("sign in with the API key as 'Authorization: Bearer <key>', not with a session")
    with context.database.writing() as session:
        token, expires_at = open_session(session, key, ttl=timedelta(seconds=context.settings.session_ttl_s))
    response.set_cookie(
        SESSION_COOKIE,
        token,
        max_age=int(context.settings.session_ttl_s),
        path="/",
        httponly=True,
        samesite="strict",
        secure=request.url.scheme == "https",
    )
    return SessionOut(key=key_out(key), expires_at=expires_at)


@router.delete("", status_code=204, response_class=Response)
def sign_out(request: Request, context: ContextDep) -> Response:
    """Sign the browser out: its session is forgotten and its cookie cleared (also when already gone)."""
    token = request.cookies.get(SESSION_COOKIE)
    if token:
        with context.database.writing() as session:
            close_session(session, token)
    response = Response(status_code=204)
    response.delete_cookie(SESSION_COOKIE, path="/", httponly=True, samesite="strict")
    return response
