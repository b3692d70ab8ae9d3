"""CSV cells that a spreadsheet shows as text, never runs as a formula.

Orchard, row and tree names come from the field (capture.json): a name such as ``=HYPERLINK(...)`` or
``+1-2`` would be run as a formula by Excel or LibreOffice when a grower opens the export. Such a cell
gets a leading apostrophe, which spreadsheets read as "this is text" (the OWASP rule for CSV injection).
"""

from __future__ import annotations

__all__ = ["safe_cell"]

_FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def safe_cell(value: object) -> object:
    """``value`` as a CSV cell: text that a spreadsheet would take for a formula is prefixed with ``'``;
    numbers and other text are unchanged."""
    if isinstance(value, str) and value.startswith(_FORMULA_STARTS):
        return "'" + value
    return value
