"""Blobs in an S3-compatible object store (``CANOPY_S3_BUCKET``): a capture measured end to end with its
files, cloud and figures in the bucket and none in the data folder, on SQLite and PostgreSQL; the
collector's claims against writers of the same bytes; an object store that does not answer.

The object store is moto's S3 server (``tests/service/s3.py``); the service and its worker reach it over
HTTP with boto3 as they would MinIO or AWS. moto does not check the SHA-256 a PUT carries, which MinIO and
S3 do.
"""

from __future__ import annotations

import json
import threading
import time
import uuid
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path

import boto3
import pytest

from service.blob_gc import collect_garbage
from service.blob_registry import BlobRegistry
from service.database import Database
from service.migrate import upgrade
from service.models import StoredBlob
from service.object_store import ObjectStore
from service.storage import sha256_hex
from tests.service.postgres import BACKENDS, database_url
from tests.service.running import (
    capture_files,
    content_digest,
    free_port,
    start_service,
    upload_capture,
    wait_for_job,
)
from tests.service.s3 import CREDENTIALS, s3_server


@pytest.fixture(scope="module")
def s3_url() -> Iterator[str]:
    """The URL of an S3 server on this machine."""
    with s3_server() as url:
        yield url


@pytest.fixture
def credentials(monkeypatch: pytest.MonkeyPatch) -> None:
    """The object store's credentials in the environment, of this process and of the services it starts."""
    for name, value in CREDENTIALS.items():
        monkeypatch.setenv(name, value)


@pytest.fixture
def bucket(s3_url: str, credentials: None) -> str:
    """A new, empty bucket."""
    name = f"canopy-{uuid.uuid4().hex[:12]}"
    boto3.client("s3", endpoint_url=s3_url).create_bucket(Bucket=name)
    return name


def _objects(s3_url: str, bucket: str) -> dict[str, bytes]:
    client = boto3.client("s3", endpoint_url=s3_url)
    keys = [entry["Key"] for entry in client.list_objects_v2(Bucket=bucket).get("Contents", [])]
    return {key: client.get_object(Bucket=bucket, Key=key)["Body"].read() for key in keys}


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_capture_is_measured_with_every_blob_in_the_bucket_and_collected_there(
    backend: str, s3_url: str, bucket: str, tree_capture: Path, tmp_path: Path
) -> None:
    with database_url(backend) as url:
        service = start_service(
            tmp_path,
            database_url=url,
            s3_bucket=bucket,
            s3_endpoint_url=s3_url,
            blob_gc_grace_s="0",
            worker_poll_s="0.1",
        )
        try:
            service.start_worker()
            with service.client() as client:
                capture_id = upload_capture(client, tree_capture)
                job = wait_for_job(client, client.post(f"/v1/captures/{capture_id}/jobs").headers["location"])
                assert job["state"] == "succeeded", job
                [(measurement_id, cloud_sha256, figures)] = service.query(
                    "SELECT id, cloud_sha256, figures FROM measurements"
                )
                cloud = client.get(f"/v1/measurements/{measurement_id}/cloud.ply")
                assert cloud.status_code == 200
                assert sha256_hex(cloud.content) == cloud_sha256
                assert cloud.headers["content-disposition"] == (
                    f'attachment; filename="measurement-{measurement_id}.ply"'
                )
                assert client.get(f"/v1/measurements/{measurement_id}/report").status_code == 200

            figures = json.loads(figures) if isinstance(figures, str) else figures
            files = {path: digest for path, digest in service.query("SELECT path, sha256 FROM capture_files")}
            named = {*files.values(), cloud_sha256, *figures.values()}
            objects = _objects(s3_url, bucket)
            assert {key.rsplit("/", 1)[1] for key in objects} == named
            assert all(key == f"blobs/{digest[:2]}/{digest}" for key in objects for digest in [key[-64:]])
            assert all(sha256_hex(data) == key.rsplit("/", 1)[1] for key, data in objects.items())
            assert {digest for (digest,) in service.query("SELECT sha256 FROM stored_blobs")} == named
            assert not (service.data_dir / "blobs").exists()
            assert list((service.data_dir / "spool").iterdir()) == []

            with service.client() as client:
                assert client.delete(f"/v1/captures/{capture_id}").status_code == 204
            collected = service.canopy("gc")
            assert collected.returncode == 0, collected.stderr
            assert f"removed {len(named)} " in collected.stdout
            assert _objects(s3_url, bucket) == {}
            assert service.query("SELECT sha256 FROM stored_blobs") == []
        finally:
            service.stop()


@pytest.fixture(params=BACKENDS)
def store(request: pytest.FixtureRequest, s3_url: str, bucket: str, tmp_path: Path) -> Iterator[ObjectStore]:
    """An object store on a migrated database whose collector's claims last 2 s."""
    with database_url(request.param) as url:
        database = Database(url or f"sqlite:///{tmp_path / 'blobs.db'}")
        try:
            upgrade(database)
            (tmp_path / "spool").mkdir()
            yield ObjectStore(
                s3_url,
                bucket,
                prefix="blobs/",
                registry=BlobRegistry(database, claim_s=2.0),
                spool_dir=tmp_path / "spool",
                attempts=2,
            )
        finally:
            database.dispose()


def _age(store: ObjectStore, sha256: str, by_s: float) -> None:
    """Make the blob look last committed ``by_s`` ago."""
    with store.registry.database.writing() as session:
        row = session.get(StoredBlob, sha256)
        assert row is not None
        row.committed_at -= timedelta(seconds=by_s)


def test_bytes_committed_since_the_grace_began_are_kept_and_older_ones_go(store: ObjectStore) -> None:
    old = store.put(b"the cloud of a capture deleted last week")
    recent = store.put(b"stored a moment ago; its record is on its way")
    _age(store, old, 7200)
    since = time.time() - 3600
    assert store.remove_unless_touched(recent, since=since) is None
    assert store.read(recent) == b"stored a moment ago; its record is on its way"
    assert store.remove_unless_touched(old, since=since) == len(b"the cloud of a capture deleted last week")
    with pytest.raises(FileNotFoundError):
        store.read(old)
    assert {digest for digest, _ in store.stored()} == {recent}


def test_a_writer_of_claimed_bytes_waits_for_the_delete_and_stores_them_again(store: ObjectStore) -> None:
    data = b"the same figure, measured again"
    digest = store.put(data)
    _age(store, digest, 7200)
    claim = store.registry.claim(digest, since=time.time() - 3600)
    assert claim is not None
    writer = threading.Thread(target=store.put, args=(data,))
    writer.start()
    writer.join(timeout=0.5)
    assert writer.is_alive(), "the writer went on while a collector held a live claim on its bytes"
    assert store.registry.holds(digest, claim)
    store.client.delete_object(Bucket=store.bucket, Key=store.key(digest))
    store.registry.forget(digest, claim)
    writer.join(timeout=10)
    assert not writer.is_alive()
    assert store.read(digest) == data
    assert store.remove_unless_touched(digest, since=time.time() - 3600) is None


def test_a_collector_too_slow_to_delete_gives_up_and_its_claim_lapses(store: ObjectStore) -> None:
    data = b"a blob whose collector stalled"
    digest = store.put(data)
    _age(store, digest, 7200)
    claim = store.registry.claim(digest, since=time.time() - 3600)
    assert claim is not None
    assert store.registry.claim(digest, since=time.time() - 3600) is None  # one collector at a time
    time.sleep(store.registry.claim_s / 2 + 0.2)
    assert not store.registry.holds(digest, claim)  # past half its claim, it must not delete
    time.sleep(store.registry.claim_s / 2)
    started = time.monotonic()
    store.put(data)  # the lapsed claim does not hold a writer up
    assert time.monotonic() - started < store.registry.claim_s / 2
    assert store.read(digest) == data


def test_a_writer_that_takes_over_a_lapsed_claim_writes_its_bytes_again(store: ObjectStore) -> None:
    """A collector's claim lapsed while its delete was in flight: the object may vanish any moment, so the
    writer that takes the blob over stores its bytes again rather than trust the object it finds."""
    data = b"a figure whose collector stalled mid-delete"
    digest = store.put(data)
    _age(store, digest, 7200)
    assert store.registry.claim(digest, since=time.time() - 3600) is not None
    damaged = bytes(len(data))  # stands for an object the late delete is about to take away
    store.client.put_object(Bucket=store.bucket, Key=store.key(digest), Body=damaged)
    time.sleep(store.registry.claim_s + 0.1)
    store.put(data)
    assert store.read(digest) == data


def test_objects_under_the_prefix_that_are_not_blobs_are_left_alone(store: ObjectStore) -> None:
    digest = sha256_hex(b"not stored under its own first two digits")
    strays = [
        f"blobs/notes/{digest}",
        f"blobs/{'00' if digest[:2] != '00' else '11'}/{digest}",
        "blobs/README",
    ]
    for key in strays:
        store.client.put_object(Bucket=store.bucket, Key=key, Body=b"someone else's")
    done = collect_garbage(store.registry.database, store, grace_s=0)
    assert (done.blobs, done.removed) == (0, 0)
    assert sorted(_objects_of(store)) == sorted(strays)


def _objects_of(store: ObjectStore) -> list[str]:
    return [entry["Key"] for entry in store.client.list_objects_v2(Bucket=store.bucket).get("Contents", [])]


def test_an_object_no_writer_registered_is_collected(store: ObjectStore) -> None:
    data = b"left in the bucket by an earlier installation"
    digest = sha256_hex(data)
    store.client.put_object(Bucket=store.bucket, Key=store.key(digest), Body=data)
    store.put(b"a blob stored through the register, whose record never came")
    done = collect_garbage(store.registry.database, store, grace_s=0)
    assert (done.blobs, done.removed) == (2, 2)  # no record names either
    assert list(store.stored()) == []


def test_an_object_store_that_does_not_answer_refuses_the_upload_and_stores_nothing(
    tmp_path: Path, tree_capture: Path, credentials: None
) -> None:
    nowhere = f"http://127.0.0.1:{free_port()}"
    service = start_service(tmp_path, s3_bucket="canopy-nowhere", s3_endpoint_url=nowhere, s3_attempts="1")
    try:
        with service.client() as client:
            created = client.post("/v1/captures", content=(tree_capture / "capture.json").read_bytes())
            assert created.status_code == 201, created.text
            path, data = next(iter(capture_files(tree_capture).items()))
            answer = client.put(
                f"/v1/captures/{created.json()['id']}/files/{path}",
                content=data,
                headers={"Content-Digest": content_digest(data)},
            )
        assert answer.status_code == 503, answer.text
        assert answer.headers["content-type"] == "application/problem+json"
        assert answer.json()["code"] == "object_store_unavailable"
        assert answer.headers["retry-after"] == "5"
        with service.client() as client:
            ready = client.get("/readyz")
        assert ready.status_code == 503
        assert "blob store" in ready.json()["detail"] and "canopy-nowhere" in ready.json()["detail"]
        assert service.query("SELECT path FROM capture_files") == []
        assert list((service.data_dir / "spool").iterdir()) == []
    finally:
        service.stop()


def test_a_job_whose_store_goes_away_is_handed_back_and_measured_once_it_returns(
    tree_capture: Path, tmp_path: Path, credentials: None
) -> None:
    """The object store stops answering after the upload: the worker cannot read the capture's files, hands
    the job back without counting the attempt, and measures it once the store answers again."""
    port = free_port()
    bucket = f"canopy-{uuid.uuid4().hex[:12]}"
    with s3_server(port) as s3_url:
        boto3.client("s3", endpoint_url=s3_url).create_bucket(Bucket=bucket)
        service = start_service(tmp_path, s3_bucket=bucket, s3_endpoint_url=s3_url, s3_attempts="1")
        try:
            with service.client() as client:
                capture_id = upload_capture(client, tree_capture)
                job_url = client.post(f"/v1/captures/{capture_id}/jobs").headers["location"]
        except BaseException:
            service.stop()
            raise
    try:
        service.start_worker()
        log = service.data_dir / "worker-0.log"
        deadline = time.monotonic() + 60
        while "the object store did not answer" not in (log.read_text() if log.exists() else ""):
            assert time.monotonic() < deadline, "the worker never met the missing store"
            time.sleep(0.2)
        with service.client() as client:
            job = client.get(job_url).json()
            assert (job["state"], job["attempts"]) == ("queued", 0), job
            with s3_server(port):
                job = wait_for_job(client, job_url)
        assert job["state"] == "succeeded", job
        assert job["attempts"] == 1
    finally:
        service.stop()
