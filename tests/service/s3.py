"""The S3-compatible server the object-store tests and `bench/scale.py --object-store` run against: moto's,
a real HTTP server speaking the S3 API, started in the calling process (no MinIO binary can be installed
on the test machine). It keeps its buckets in that process, so one restarted on the same port finds them."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from moto.server import ThreadedMotoServer

from tests.service.running import free_port

__all__ = ["CREDENTIALS", "s3_server"]

CREDENTIALS = {
    "AWS_ACCESS_KEY_ID": "canopy",
    "AWS_SECRET_ACCESS_KEY": "canopy-secret",
    "AWS_REGION": "us-east-1",
}
"""What the services under test get in their environment, as the AWS SDK reads it."""


@contextmanager
def s3_server(port: int | None = None) -> Iterator[str]:
    """An S3 server on ``port`` (a free one by default) while the block runs; its URL."""
    port = port or free_port()
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.stop()
