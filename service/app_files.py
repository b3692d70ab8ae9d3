"""Where the service's own files for browsers live."""

from __future__ import annotations

from pathlib import Path

__all__ = ["STATIC_DIR"]

STATIC_DIR = Path(__file__).parent / "static"
"""The pages' scripts and their vendored libraries (three.js), served at ``/static`` without a key."""
