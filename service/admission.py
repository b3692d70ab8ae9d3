"""How much work the API takes on at once: file uploads overall and per API key, and image checks.

An upload holds a slot from before its body is read until it is stored; beyond the caps the request is
refused at once with Retry-After (503 when the server is full, 429 when one key holds its share), so a few
clients cannot take every connection. Image checks (decoding an upload to prove it readable) wait their
turn instead, on a few threads of their own: each holds the image's pixels, so their number bounds the
API's memory; and the memory a thread frees stays with that thread's allocator arena, so checks spread
over the server's general thread pool would each keep an image's worth of memory after they are done.

One instance per API process, used only from its event loop (no locking needed).
"""

from __future__ import annotations

import asyncio
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import TypeVar

from service.errors import ServiceBusy, TooManyRequests
from service.settings import Settings

__all__ = ["Admission"]

T = TypeVar("T")

RETRY_UPLOAD_S = 2
"""When a refused upload may try again: uploads of a capture's files last seconds."""


class Admission:
    """The API process's upload slots and image-check turns, sized by the settings."""

    def __init__(self, settings: Settings) -> None:
        self.max_uploads = settings.max_concurrent_uploads
        self.max_uploads_per_key = settings.max_uploads_per_key
        self.image_checks = ThreadPoolExecutor(
            settings.max_concurrent_image_checks, thread_name_prefix="image-check"
        )
        self._uploads: Counter[int] = Counter()

    async def check_image(self, check: Callable[[], T]) -> T:
        """Run ``check`` (which decodes an image) on the image-check threads, waiting for a turn."""
        return await asyncio.get_running_loop().run_in_executor(self.image_checks, check)

    @property
    def uploads(self) -> int:
        """File bodies being received now."""
        return self._uploads.total()

    @contextmanager
    def upload(self, key_id: int, *, file: str) -> Iterator[None]:
        """Hold an upload slot for the key ``key_id`` while the block runs; refused (``file`` named) when
        every slot, or the key's share of them, is taken."""
        if self._uploads[key_id] >= self.max_uploads_per_key:
            raise TooManyRequests(
                f"this API key is sending {self._uploads[key_id]} files already, its limit; send {file} "
                "when one of them is done",
                retry_after_s=RETRY_UPLOAD_S,
                file=file,
            )
        if self.uploads >= self.max_uploads:
            raise ServiceBusy(
                f"the server is receiving {self.uploads} files, its limit; send {file} again shortly",
                retry_after_s=RETRY_UPLOAD_S,
                file=file,
            )
        self._uploads[key_id] += 1
        try:
            yield
        finally:
            self._uploads[key_id] -= 1
            if not self._uploads[key_id]:
                del self._uploads[key_id]
