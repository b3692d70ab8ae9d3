"""HTTP requests that outlast flaky Wi-Fi: retries with exponential backoff and full jitter.

Connection errors, timeouts, 5xx, 408 and 429 are retried (honouring Retry-After) until ``retry_for_s``
has passed since the request first failed, and the first failure of an outage is said at once, in plain
words, as is the end of it; any other 4xx is final and raised as :class:`RequestRefused` with the server's
problem details. What retrying cannot mend (an address without http:// or https://, TLS spoken to a plain
HTTP server, a server that is not Canopy) is raised at once as :class:`ServerUnusable`.

Every request the client makes is idempotent on the server (capture creation by tree and time, files by
path and digest, jobs by Idempotency-Key), so a retry after a lost answer never duplicates anything.
"""

from __future__ import annotations

import email.utils
import random
import ssl
import time
from collections.abc import Callable
from typing import Any

import httpx

__all__ = ["RequestRefused", "ServerUnreachable", "ServerUnusable", "Transport"]

_RETRIED_STATUSES = {408, 429}


class RequestRefused(Exception):
    """The server refused a request for good (a 4xx other than 408/429, or a redirect): what it said."""

    def __init__(self, response: httpx.Response) -> None:
        self.status = response.status_code
        try:
            self.problem: dict[str, Any] = response.json()
        except ValueError:
            self.problem = {"detail": response.text[:500]}
        detail = self.problem.get("detail") or self.problem.get("title") or response.reason_phrase
        if 300 <= self.status < 400:
            detail = f"redirected to {response.headers.get('location')}; is --server the service's address?"
        super().__init__(f"HTTP {self.status}: {detail}")


class ServerUnreachable(Exception):
    """The server did not answer usefully for ``retry_for_s`` seconds; the last problem is the message."""


class ServerUnusable(Exception):
    """The address cannot work as given, however long one retries: the message says why and what to try."""


def _checked_address(server: str) -> str:
    """``server`` without a trailing slash; ServerUnusable unless it is an http:// or https:// address."""
    try:
        url = httpx.URL(server)
    except httpx.InvalidURL as exc:
        raise ServerUnusable(f"--server {server!r} is not an address: {exc}") from exc
    if url.scheme not in ("http", "https") or not url.host:
        raise ServerUnusable(
            f"--server {server!r} is not an http:// or https:// address; did you mean http://{server}?"
        )
    return server.rstrip("/")


def _tls_failure(exc: BaseException) -> ssl.SSLError | None:
    """The TLS error behind a transport error, if any (an https:// address of a plain HTTP server)."""
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, ssl.SSLError):
            return seen
        seen = seen.__cause__ or seen.__context__
    return None


def _plain(exc: httpx.TransportError) -> str:
    """A transport error in a crew's words."""
    text = str(exc).lower()
    if isinstance(exc, httpx.ConnectTimeout):
        return "no answer (connection timed out)"
    if isinstance(exc, httpx.ConnectError):
        if "refused" in text:
            return "connection refused (is the service running on that port?)"
        if "name or service" in text or "nodename" in text or "name resolution" in text:
            return "unknown host name"
        if "unreachable" in text:
            return "network unreachable"
        return f"cannot connect ({exc})"
    if isinstance(exc, httpx.TimeoutException):
        return "the connection stalled (timed out)"
    if isinstance(exc, httpx.RemoteProtocolError):
        return "the server closed the connection"
    return f"the connection broke ({type(exc).__name__}: {exc})"


class Transport:
    """An HTTP client for one server and key that retries what is worth retrying.

    Parameters
    ----------
    server
        Base address, e.g. ``http://10.0.0.5:8000``.
    key
        API key with the ``capture`` scope (and ``read`` to wait for results).
    retry_for_s
        Give a failing request up after this long (then :class:`ServerUnreachable`).
    timeout_s
        Per attempt: connect, and each read or write of the connection.
    first_backoff_s, max_backoff_s
        The wait before the first retry, doubling up to the cap; each wait is drawn uniformly below it
        (full jitter). The cap bounds how late the client notices that the network is back.
    sleep, clock
        How to wait and tell the time (``time.sleep``, ``time.monotonic``; tests give a simulated pair).
    notice
        Told, in a sentence, when the server stops answering (at the first failure, with how long the
        client will keep trying) and when it answers again.

    Raises
    ------
    ServerUnusable
        ``server`` is not an http:// or https:// address.
    """

    def __init__(
        self,
        server: str,
        key: str,
        *,
        retry_for_s: float = 300.0,
        timeout_s: float = 30.0,
        first_backoff_s: float = 0.25,
        max_backoff_s: float = 5.0,
        sleep: Callable[[float], None] = time.sleep,
        clock: Callable[[], float] = time.monotonic,
        notice: Callable[[str], None] | None = None,
    ) -> None:
        self.server = _checked_address(server)
        self._client = httpx.Client(
            base_url=self.server,
            headers={"Authorization": f"Bearer {key}", "User-Agent": "canopy-upload/1"},
            timeout=timeout_s,
        )
        self.retry_for_s = retry_for_s
        self._first_backoff_s = first_backoff_s
        self._max_backoff_s = max_backoff_s
        self._sleep = sleep
        self._clock = clock
        self._notice = notice
        self._outage_since: float | None = None

    def sleep(self, seconds: float) -> None:
        """Pause (through the sleep this transport was given, so that tests can count it)."""
        self._sleep(seconds)

    def close(self) -> None:
        """Close the connections."""
        self._client.close()

    def request(self, method: str, path: str, **options: Any) -> httpx.Response:
        """Send a request until it gets a final answer: a 2xx response, or RequestRefused.

        ``retry_for_s`` counts from the request's first failure, so a long transfer that fails near its end
        is still retried.
        """
        first_failure: float | None = None
        attempt = 0
        while True:
            try:
                response = self._client.request(method, path, **options)
            except httpx.TransportError as exc:
                tls = _tls_failure(exc)
                if tls is not None:
                    raise ServerUnusable(
                        f"cannot speak TLS with {self.server} ({tls.reason or tls}): if the service is plain "
                        f"HTTP, use {self.server.replace('https://', 'http://', 1)}"
                    ) from exc
                problem, wait_s = _plain(exc), None
            else:
                if response.status_code < 500 and response.status_code not in _RETRIED_STATUSES:
                    self._answered()
                if 200 <= response.status_code < 300:
                    return response
                if response.status_code < 400:
                    # A redirect (to https, or a Wi-Fi login page) is not the API answering.
                    raise RequestRefused(response)
                if response.status_code < 500 and response.status_code not in _RETRIED_STATUSES:
                    raise RequestRefused(response)
                problem = f"HTTP {response.status_code} {response.reason_phrase}"
                wait_s = _retry_after_s(response)
            backoff_s = random.uniform(0, min(self._max_backoff_s, self._first_backoff_s * 2**attempt))
            wait_s = max(wait_s or 0.0, backoff_s)
            first_failure = self._clock() if first_failure is None else first_failure
            if self._outage_since is None:
                self._outage_since = first_failure
                self._say(
                    f"cannot reach {self.server}: {problem}; retrying for up to {self.retry_for_s:g} s "
                    "(Ctrl-C to stop)"
                )
            if self._clock() + wait_s - first_failure > self.retry_for_s:
                raise ServerUnreachable(
                    f"{self.server} did not answer {method} {path} for {self.retry_for_s:g} s: {problem}"
                )
            self._sleep(wait_s)
            attempt += 1

    def identify(self) -> dict[str, Any]:
        """The key this transport sends and the service's version (``GET /v1/keys/current``).

        Raises
        ------
        ServerUnusable
            The address answers, but not as a Canopy service.
        RequestRefused
            The key is unknown or revoked (401).
        ServerUnreachable
            Nothing answered for ``retry_for_s``.
        """
        try:
            answer = self.request("GET", "/v1/keys/current")
            identity = answer.json()
            known = identity.get("service") == "canopy" and isinstance(identity["key"]["scopes"], list)
        except RequestRefused as exc:
            if exc.status in (401, 403):
                raise
            raise ServerUnusable(
                f"{self.server} answers, but not as a Canopy service ({exc}); check --server"
            ) from exc
        except (ValueError, KeyError, TypeError, AttributeError):
            known = False
        if not known:
            raise ServerUnusable(f"{self.server} answers, but not as a Canopy service; check --server")
        return identity

    def _answered(self) -> None:
        """The server answered: say so when it had stopped."""
        if self._outage_since is not None:
            self._say(f"reached {self.server} again after {self._clock() - self._outage_since:.0f} s")
            self._outage_since = None

    def _say(self, message: str) -> None:
        if self._notice is not None:
            self._notice(message)


def _retry_after_s(response: httpx.Response) -> float | None:
    """Retry-After as seconds (RFC 9110: delay-seconds or an HTTP date), or None."""
    value = response.headers.get("retry-after")
    if value is None:
        return None
    if value.strip().isdigit():
        return float(value)
    try:
        moment = email.utils.parsedate_to_datetime(value)
    except (TypeError, ValueError):
        return None
    return max(0.0, moment.timestamp() - time.time())
