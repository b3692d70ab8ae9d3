"""The service's own errors: what its domain code (captures, jobs, keys, the farm, validation) raises when
a request cannot be done, naming the field, file or view at fault.

They know nothing of HTTP, so the worker and the command line use the same code without loading the web
framework; ``service/problems.py`` is the one place that turns each kind into a status and a problem+json
answer.
"""

from __future__ import annotations

from typing import Any, ClassVar

__all__ = [
    "BadRequest",
    "ComeBackLater",
    "Conflict",
    "Forbidden",
    "InsufficientStorage",
    "InvalidContent",
    "NotFound",
    "NotReady",
    "PayloadTooLarge",
    "RequestTimeout",
    "ServiceBusy",
    "ServiceError",
    "TooManyRequests",
    "Unauthorized",
]


class ServiceError(Exception):
    """A request the service refuses; ``code`` is the stable, machine-readable kind.

    Locations (``field``, ``file``, ``view``) and any other keyword arguments are members of the error
    (each becomes a member of the problem object, so clients never parse ``detail``).
    """

    code: ClassVar[str] = "internal_error"

    def __init__(self, detail: str, *, code: str | None = None, **members: Any) -> None:
        super().__init__(detail)
        self.detail = detail
        self.instance_code = code or self.code
        self.members = {key: value for key, value in members.items() if value is not None}


class BadRequest(ServiceError):
    """The request itself is malformed (a parameter, a header, a path)."""

    code = "bad_request"


class Unauthorized(ServiceError):
    """No key, or a key that is unknown, revoked or expired."""

    code = "unauthorized"


class Forbidden(ServiceError):
    """The key lacks the scope the request needs."""

    code = "forbidden"


class NotFound(ServiceError):
    """The thing named does not exist, or the key may not see it."""

    code = "not_found"


class RequestTimeout(ServiceError):
    """A body stopped arriving before it was whole."""

    code = "body_timeout"


class Conflict(ServiceError):
    """The request contradicts what is stored (a file already there with other bytes, a job running)."""

    code = "conflict"


class PayloadTooLarge(ServiceError):
    """A body beyond the configured limit."""

    code = "body_too_large"


class InvalidContent(ServiceError):
    """What was sent is well-formed but wrong (a capture's manifest, a CSV row, a file's digest)."""

    code = "invalid_content"


class ComeBackLater(ServiceError):
    """A refusal the same request may not meet later: it says when to try again, in seconds."""

    def __init__(self, detail: str, *, retry_after_s: int, code: str | None = None, **members: Any) -> None:
        super().__init__(detail, code=code, **members)
        self.retry_after_s = retry_after_s


class NotReady(ServiceError):
    """The service cannot answer yet: its database does not."""

    code = "not_ready"


class TooManyRequests(ComeBackLater):
    """A key's share of the concurrent uploads is taken."""

    code = "too_many_uploads"


class ServiceBusy(ComeBackLater):
    """The whole service is at its limit of concurrent uploads."""

    code = "service_busy"


class InsufficientStorage(ComeBackLater):
    """The data disk is at its floor of free space: nothing is stored."""

    code = "out_of_space"
