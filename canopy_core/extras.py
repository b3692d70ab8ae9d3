"""The optional parts of the install and the commands that need them.

The base install is the measurement core and the capture client; the service (``canopy[service]``) and
the simulator (``canopy[sim]``) are extras. A command whose extra is missing says which to install rather
than failing on an import deep inside.
"""

from __future__ import annotations

from importlib.util import find_spec

import typer

__all__ = ["EXTRAS", "missing_modules", "require_extra"]

EXTRAS: dict[str, tuple[str, ...]] = {
    "service": ("fastapi", "uvicorn", "sqlalchemy", "alembic", "psycopg", "matplotlib", "laspy", "jinja2"),
    "sim": ("open3d",),
}
"""Each extra, by the modules that show it is installed (pyproject.toml lists its packages)."""


def missing_modules(extra: str) -> list[str]:
    """The modules of ``extra`` that cannot be imported here."""
    return [module for module in EXTRAS[extra] if find_spec(module) is None]


def require_extra(extra: str, command: str) -> None:
    """Exit with code 2 and one line naming the extra to install when ``command`` cannot run here."""
    missing = missing_modules(extra)
    if missing:
        typer.echo(
            f"error: `canopy {command}` needs the {extra} extra ({', '.join(missing)} not installed): "
            f"pip install 'canopy[{extra}]'",
            err=True,
        )
        raise typer.Exit(2)
