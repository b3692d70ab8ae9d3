"""The HTTP/1.1 protocol the API is served with: uvicorn's (h11), answering what it cannot parse as a
problem+json 400 like every other error, instead of uvicorn's plain-text one.

A request line or header that is not HTTP (``Content-Length: -1``, a header without a colon, a bare line
feed) is refused below FastAPI, before any route or middleware sees it; this is the one place left to say
so in the API's own format. The connection is closed after it, as the rest of its bytes cannot be framed.
"""

from __future__ import annotations

import json

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

from service.problems import PROBLEM_JSON

__all__ = ["ProblemH11Protocol"]


class ProblemH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with its 400 for unparsable requests in problem+json."""

    def send_400_response(self, msg: str) -> None:
        body = json.dumps(
            {
                "type": "/problems/malformed_request",
                "title": "Malformed request",
                "status": 400,
                "detail": f"the request is not valid HTTP/1.1 ({msg}); the connection is closed",
                "code": "malformed_request",
            }
        ).encode()
        headers = [
            (b"content-type", PROBLEM_JSON.encode()),
            (b"content-length", str(len(body)).encode()),
            (b"connection", b"close"),
        ]
        for event in (
            h11.Response(status_code=400, headers=headers, reason=b"Bad Request"),
            h11.Data(data=body),
            h11.EndOfMessage(),
        ):
            self.transport.write(self.conn.send(event))
        self.transport.close()
