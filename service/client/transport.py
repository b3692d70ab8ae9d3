"""HTTP requests that outlast flaky Wi-Fi: retries with exponential backoff and full jitter.

Connection errors, timeouts, 5xx, 408 and 429 are retried (honouring Retry-After) until ``retry_for_s``
has passed since the request first failed; any other 4xx is final and raised as :class:`RequestRefused`
with the server's problem details. Every request the client makes is idempotent on the server (capture
creation by tree and time, files by path and digest, jobs by Idempotency-Key), so a retry after a lost
answer never duplicates anything.
"""

from __future__ import annotations

import email.utils
import random
import time
from collections.abc import Callable
from typing import Any

import httpx

__all__ = ["RequestRefused", "ServerUnreachable", "Transport"]

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
    ) -> None:
        self.server = server.rstrip("/")
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
                problem, wait_s = f"{type(exc).__name__}: {exc}", None
            else:
                if 200 <= response.status_code < 300:
                    return response
                if response.status_code < 400:
                    # A redirect (to https, or a Wi-Fi login page) is not the API answering.
                    raise RequestRefused(response)
                if response.status_code < 500 and response.status_code not in _RETRIED_STATUSES:
                    raise RequestRefused(response)
                problem = f"HTTP {response.status_code}"
                wait_s = _retry_after_s(response)
            backoff_s = random.uniform(0, min(self._max_backoff_s, self._first_backoff_s * 2**attempt))
            wait_s = max(wait_s or 0.0, backoff_s)
            first_failure = self._clock() if first_failure is None else first_failure
            if self._clock() + wait_s - first_failure > self.retry_for_s:
                raise ServerUnreachable(f"{method} {path}: {problem} (gave up after {self.retry_for_s:g} s)")
            self._sleep(wait_s)
            attempt += 1


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
