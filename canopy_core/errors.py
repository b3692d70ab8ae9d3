"""The one exception hierarchy of the measurement core.

Every error names where the problem is (view, file, field, colour) and what to do about it, so the CLI can
print it as one line and the service can map it to a problem+json response without parsing messages.
"""

from __future__ import annotations

__all__ = [
    "BallNotFound",
    "CanopyError",
    "CaptureError",
    "ConfigError",
    "MeasurementError",
    "RegistrationFailed",
]


class CanopyError(Exception):
    """Base class of every error the measurement core raises on purpose.

    Parameters
    ----------
    message
        What is wrong, in one sentence.
    view
        The capture's view name (``"views/1"``) the problem concerns, if any.
    file
        The file path inside the capture folder (``"views/1/depth.png"``), if any.
    field
        The JSON field (dotted path, ``"depth_intrinsics.fx"``), if any.
    hint
        What the user can do about it, if there is something useful to say.
    """

    code = "canopy_error"

    def __init__(
        self,
        message: str,
        *,
        view: str | None = None,
        file: str | None = None,
        field: str | None = None,
        hint: str | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.view = view
        self.file = file
        self.field = field
        self.hint = hint

    def __str__(self) -> str:
        where = self.file or self.view
        text = f"{where}: {self.message}" if where else self.message
        if self.field and self.field not in self.message:
            text = f"{text} (field {self.field})"
        return _with_hint(text, self.hint)

    def __reduce__(self) -> tuple[object, ...]:
        # Keyword-only locations would be lost by Exception's default pickling (it replays ``args``);
        # errors must cross process boundaries intact (worker children, process pools).
        return (_rebuild, (type(self), dict(self.__dict__)))

    def to_dict(self) -> dict[str, str]:
        """The error as a flat JSON object: ``code``, ``message`` and whichever locations are known."""
        out = {"code": self.code, "message": self.message}
        for key in ("view", "file", "field", "hint"):
            value = getattr(self, key)
            if value is not None:
                out[key] = value
        return out


def _rebuild(cls: type[CanopyError], state: dict[str, object]) -> CanopyError:
    error = cls.__new__(cls)
    Exception.__init__(error, state["message"])
    error.__dict__.update(state)
    return error


class CaptureError(CanopyError):
    """The capture folder or one of its files is missing, unreadable or inconsistent."""

    code = "invalid_capture"


class ConfigError(CanopyError):
    """Measurement settings given by the caller are invalid (names the setting)."""

    code = "invalid_config"


class MeasurementError(CanopyError):
    """The capture is well formed but the measurement cannot be made from it."""

    code = "measurement_failed"


class BallNotFound(MeasurementError):
    """A calibration ball of one colour was not found, or what was found is not a plausible ball."""

    code = "ball_not_found"

    def __init__(self, message: str, *, view: str, color: str, hint: str | None = None) -> None:
        super().__init__(message, view=view, hint=hint)
        self.color = color

    def __str__(self) -> str:
        return _with_hint(f"{self.view}: {self.color} ball: {self.message}", self.hint)

    def to_dict(self) -> dict[str, str]:
        """As :meth:`CanopyError.to_dict`, with the ball's ``color``."""
        return {**super().to_dict(), "color": self.color}


class RegistrationFailed(MeasurementError):
    """The views could not be brought into one frame (balls inconsistent between views, or too few)."""

    code = "registration_failed"


def _with_hint(text: str, hint: str | None) -> str:
    """``text`` and then ``hint`` as a sentence of its own (no second stop after a question)."""
    if not hint:
        return text
    return f"{text} {hint}" if text.endswith(("?", ".", "!")) else f"{text}. {hint}"
