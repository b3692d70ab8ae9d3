"""Pydantic's validation errors as the sentences Canopy's errors carry, for capture files and measurement
settings alike: each problem located by its dotted path, an unknown key named with the nearest key known
there, unknown keys first (a misspelt key also makes the key it was meant to be missing)."""

from __future__ import annotations

import difflib
from dataclasses import dataclass

from pydantic import BaseModel, ValidationError

__all__ = ["Problems", "validation_problems"]


@dataclass(frozen=True)
class Problems:
    """What a validation found wrong, ready for an error."""

    message: str
    """Every problem, ``path: what`` each, joined by ``; ``."""
    field: str | None
    """The first problem's dotted path (None: the document as a whole)."""
    unknown_key: bool
    """Whether the first problem is a key the model does not know."""


def validation_problems(exc: ValidationError, model: type[BaseModel]) -> Problems:
    """The problems of ``exc``, raised validating ``model``."""
    errors = sorted(exc.errors(), key=lambda error: error["type"] != "extra_forbidden")
    problems = []
    for error in errors:
        location = ".".join(str(part) for part in error["loc"])
        message = error["msg"].removeprefix("Value error, ")
        if error["type"] == "extra_forbidden":
            message = _unknown_key(model, error["loc"])
        problems.append(f"{location}: {message}" if location else message)
    return Problems(
        message="; ".join(problems),
        field=".".join(str(part) for part in errors[0]["loc"]) or None,
        unknown_key=errors[0]["type"] == "extra_forbidden",
    )


def _unknown_key(model: type[BaseModel], location: tuple[int | str, ...]) -> str:
    """The message for the unknown key at ``location``: the nearest key known there, if any."""
    known = _keys_at(model, location[:-1])
    close = difflib.get_close_matches(str(location[-1]), known, n=1, cutoff=0.6)
    suggestion = f"; did you mean {close[0]!r}?" if close else ""
    return f"unknown field{suggestion}"


def _keys_at(model: type[BaseModel], path: tuple[int | str, ...]) -> list[str]:
    """The keys the model nested at ``path`` in ``model`` knows (none when the path leaves the models)."""
    for part in path:
        if isinstance(part, int) or part not in model.model_fields:
            return []
        annotation = model.model_fields[part].annotation
        nested = [arg for arg in (annotation, *getattr(annotation, "__args__", ())) if _is_model(arg)]
        if not nested:
            return []
        model = nested[0]
    return list(model.model_fields)


def _is_model(annotation: object) -> bool:
    return isinstance(annotation, type) and issubclass(annotation, BaseModel)
