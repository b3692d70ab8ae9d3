"""The blob garbage collector (`canopy gc`): it removes what no record names once the grace period is
over, keeps everything a record names, and never takes bytes an upload is committing at that moment."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import numpy as np
from PIL import Image

from service.storage import FolderStore
from tests.service.running import Service, upload_capture, wait_for_job

DAY_S = 86_400.0


def _age(store: FolderStore, by_s: float) -> None:
    """Make every stored blob look committed ``by_s`` ago."""
    for digest, committed in list(store.stored()):
        os.utime(store.path(digest), (committed - by_s, committed - by_s))


def _other_tree(capture: Path, into: Path) -> Path:
    """A copy of ``capture`` as another tree, its second view's depth changed (a blob of its own)."""
    copy = Path(shutil.copytree(capture, into / "other"))
    manifest = json.loads((copy / "capture.json").read_text())
    (copy / "capture.json").write_text(json.dumps({**manifest, "tree": "other"}))
    depth = copy / "views" / "2" / "depth.png"
    pixels = np.array(Image.open(depth))
    pixels[0, 0] = pixels[0, 0] + 1
    Image.fromarray(pixels).save(depth)
    return copy


def test_gc_removes_deleted_captures_and_orphans_and_keeps_every_named_blob(
    service: Service, tree_capture: Path, tmp_path: Path
) -> None:
    store = FolderStore(service.data_dir / "blobs")
    service.start_worker()
    with service.client() as client:
        kept_capture = upload_capture(client, tree_capture)
        job = wait_for_job(client, client.post(f"/v1/captures/{kept_capture}/jobs").headers["location"])
        assert job["state"] == "succeeded", job
        other = _other_tree(tree_capture, tmp_path)
        deleted_capture = upload_capture(client, other)
        query = "SELECT path, sha256 FROM capture_files WHERE capture_id = :capture"
        deleted_files = dict(service.query(query, capture=deleted_capture))
        assert client.delete(f"/v1/captures/{deleted_capture}").status_code == 204
    orphan = store.put(b"a cloud whose worker died before its record was written")
    _age(store, DAY_S)
    recent_orphan = store.put(b"stored a moment ago; its record may be on its way")
    named = {digest for (digest,) in service.query("SELECT sha256 FROM capture_files")}
    named |= {digest for (digest,) in service.query("SELECT cloud_sha256 FROM measurements")}
    [(figures,)] = service.query("SELECT figures FROM measurements")
    named |= set((json.loads(figures) if isinstance(figures, str) else figures).values())
    only_deleted = set(deleted_files.values()) - named
    assert only_deleted == {deleted_files["views/2/depth.png"]}  # the others are the kept capture's too

    counted = service.canopy("gc", "--dry-run")
    assert counted.returncode == 0, counted.stderr
    assert "would remove 2 " in counted.stdout
    assert {digest for digest, _ in store.stored()} >= named | only_deleted | {orphan, recent_orphan}

    collected = service.canopy("gc")
    assert collected.returncode == 0, collected.stderr
    assert "removed 2 " in collected.stdout
    assert {digest for digest, _ in store.stored()} == named | {recent_orphan}
    with service.client() as client:
        [measurement_id] = [row[0] for row in service.query("SELECT id FROM measurements")]
        assert client.get(f"/v1/measurements/{measurement_id}/cloud.ply").status_code == 200
        assert client.get(f"/v1/measurements/{measurement_id}/report").status_code == 200


def test_bytes_committed_again_while_the_collector_runs_are_kept(tmp_path: Path) -> None:
    (tmp_path / "blobs").mkdir()
    store = FolderStore(tmp_path / "blobs")
    data = b"the depth image of a capture deleted yesterday and uploaded again today"
    digest = store.put(data)
    _age(store, DAY_S)
    since = time.time() - 3600

    store.put(data)  # an upload of the same bytes marks them before writing its record
    assert store.remove_unless_touched(digest, since=since) is None
    assert store.read(digest) == data

    _age(store, DAY_S)
    aside = store.path(digest).with_name(f".doomed-{digest}")
    os.replace(store.path(digest), aside)  # a collector has set the blob aside and not yet checked it
    assert store.put(data) == digest  # the upload then finds no blob and stores its own copy
    assert store.read(digest) == data
    os.replace(store.path(digest), aside)
    assert store.restore_set_aside() == 1  # a collector stopped there: the next run puts it back
    assert store.read(digest) == data

    _age(store, DAY_S)
    assert store.remove_unless_touched(digest, since=since) == len(data)
    assert not store.path(digest).exists()
    assert list(store.stored()) == []
