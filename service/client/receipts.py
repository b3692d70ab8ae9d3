"""The receipt a capture folder keeps of what a server acknowledged, so an upload resumes where it stopped.

``<capture>/.canopy-receipt.json`` holds, per server address, the capture's id there, each acknowledged
file with its SHA-256, and the measurement job. It is rewritten atomically (temporary file, fsync, rename)
after every acknowledgement: a client killed at any moment leaves the previous receipt or the new one.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from pydantic import BaseModel, Field, ValidationError

__all__ = ["RECEIPT_NAME", "Receipt", "ServerReceipt"]

RECEIPT_NAME = ".canopy-receipt.json"


class ServerReceipt(BaseModel):
    """What one server acknowledged of this capture."""

    capture_id: int | None = None
    files: dict[str, str] = Field(default_factory=dict, description="path -> SHA-256 hex, acknowledged")
    job_id: int | None = None
    fingerprint: str | None = Field(
        None, description="The folder when its job was started (upload.fingerprint)"
    )


class Receipt(BaseModel):
    """Everything acknowledged of a capture folder, by server address."""

    servers: dict[str, ServerReceipt] = Field(default_factory=dict)

    @classmethod
    def load(cls, folder: Path) -> Receipt:
        """The folder's receipt; an empty one when there is none or it is unreadable (then all is re-checked
        with the server, which never duplicates a capture or a file)."""
        try:
            return cls.model_validate_json((folder / RECEIPT_NAME).read_bytes())
        except (FileNotFoundError, ValidationError, ValueError):
            return cls()

    def for_server(self, server: str) -> ServerReceipt:
        """The part for ``server``, created empty on first use."""
        return self.servers.setdefault(server, ServerReceipt())

    def save(self, folder: Path) -> None:
        """Write the receipt atomically into ``folder``."""
        descriptor, temporary = tempfile.mkstemp(dir=folder, prefix=".canopy-receipt-")
        try:
            with os.fdopen(descriptor, "w") as stream:
                stream.write(json.dumps(self.model_dump(), indent=1))
                stream.flush()
                os.fsync(stream.fileno())
            os.replace(temporary, folder / RECEIPT_NAME)
        except BaseException:
            Path(temporary).unlink(missing_ok=True)
            raise
