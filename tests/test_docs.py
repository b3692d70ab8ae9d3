"""The README and docs/ stand alone: every link and every file they name is in the repository.

A user's clone is all they have: a doc that sends them to a file outside it, or to one that moved, leaves
them without the capture format or the HTTP contract.
"""

from __future__ import annotations

import functools
import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

_LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
_CODE = re.compile(r"`([^`\s]+)`")
_SOURCE_SUFFIXES = (".py", ".md", ".toml", ".ini", ".sh")


def _top_level() -> set[str]:
    """The names a repository path starts with: its top-level folders and files, made ones left out."""
    made = {".git", ".venv", "canopy-data", "canopy.egg-info"}
    return {
        path.name
        for path in ROOT.iterdir()
        if path.name not in made and not path.name.endswith("_cache") and path.name != "__pycache__"
    }


@functools.cache
def _source_names() -> frozenset[str]:
    """The name of every file and folder in the repository, made ones left out."""
    names: set[str] = set()
    for folder, subfolders, files in os.walk(ROOT):
        subfolders[:] = [name for name in subfolders if name in _top_level() or Path(folder) != ROOT]
        subfolders[:] = [name for name in subfolders if name != "__pycache__"]
        names.update(subfolders, files)
    return frozenset(names)


def broken_references(text: str, folder: Path) -> list[str]:
    """Each link and named file of a Markdown ``text`` kept in ``folder`` that does not resolve inside the
    repository, as ``line: reference``.

    Links are checked relative to ``folder`` (web addresses and anchors are not checked); a backticked
    path is checked when it starts with one of the repository's top-level names and names a source file
    or a folder, or when it goes up (``../``); a bare source file name (``cli.py``) must be somewhere in
    the repository.
    """
    top = _top_level()
    sources = _source_names()
    broken = []
    for number, line in enumerate(text.splitlines(), start=1):
        places: list[tuple[str, Path | None]] = []
        for target in _LINK.findall(line):
            if not re.match(r"[a-z]+:", target) and not target.startswith("#"):
                places.append((target, folder / target.split("#")[0]))
        for token in _CODE.findall(line):
            path = token.rstrip(".,:;)")
            if path.startswith("../"):
                places.append((token, folder / path))
            elif path.split("/")[0] in top and (path.endswith(_SOURCE_SUFFIXES) or path.endswith("/")):
                places.append((token, ROOT / path))
            elif "/" not in path and path.endswith(_SOURCE_SUFFIXES):
                places.append((token, None))
        for reference, place in places:
            if place is None:
                found = reference.rstrip(".,:;)") in sources
            else:
                found = place.resolve().is_relative_to(ROOT) and place.exists()
            if not found:
                broken.append(f"{number}: {reference}")
    return broken


@pytest.mark.parametrize("doc", DOCS, ids=[str(doc.relative_to(ROOT)) for doc in DOCS])
def test_every_link_and_named_file_resolves_inside_the_repository(doc: Path) -> None:
    broken = broken_references(doc.read_text(encoding="utf-8"), doc.parent)
    assert not broken, f"references in {doc.relative_to(ROOT)} outside the repository or missing: {broken}"


def test_the_checker_finds_what_does_not_resolve() -> None:
    """A link to a missing page, a path outside the repository, a source file that does not exist and a
    bare file name found nowhere are each reported; a web address, an anchor and files that exist are not."""
    text = (
        "See [the format](capture-format.md), [gone](missing.md), [web](https://example.org), [top](#top).\n"
        "Read `../shared/DESIGN.md`, `service/app.py`, `service/nowhere.py`, `cli.py` and `nothing.py`.\n"
        "Files of a capture are not the repository's: `views/1/depth.png`, `capture.json`.\n"
    )
    assert broken_references(text, ROOT / "docs") == [
        "1: missing.md",
        "2: ../shared/DESIGN.md",
        "2: service/nowhere.py",
        "2: nothing.py",
    ]


def test_the_settings_reference_is_the_one_the_code_writes() -> None:
    from canopy_core.settings_reference import settings_reference

    written = (ROOT / "docs" / "configuration.md").read_text(encoding="utf-8")
    assert written == settings_reference(), "stale: run `canopy settings > docs/configuration.md`"


def test_every_setting_says_what_it_means() -> None:
    from canopy_core.config import MeasureConfig

    defaults = MeasureConfig()
    silent = [
        f"{section}.{name}"
        for section in MeasureConfig.model_fields
        for name, field in type(getattr(defaults, section)).model_fields.items()
        if not field.description
    ]
    assert silent == []
