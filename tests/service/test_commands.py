"""The service's commands: `canopy up` (the embedded default), `canopy keys`, migrations."""

from __future__ import annotations

import os
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path

import httpx
import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.config import Config
from alembic.migration import MigrationContext
from sqlalchemy import event

import migrations
from service.database import Database
from service.migrate import is_current, migration_connection, upgrade
from service.models import Base
from tests.service.postgres import BACKENDS, database_url
from tests.service.running import CANOPY, Service, free_port, start_up, stop_up

REPOSITORY = Path(__file__).resolve().parents[2]


def test_up_creates_the_database_and_prints_an_admin_key_once(tmp_path: Path) -> None:
    port = free_port()
    first, first_lines = start_up(tmp_path / "data", port)
    try:
        key = next(line.strip() for line in first_lines if line.strip().startswith("canopy_"))
        answer = httpx.get(f"http://127.0.0.1:{port}/v1/keys", headers={"Authorization": f"Bearer {key}"})
    finally:
        stop_up(first)
    second, second_lines = start_up(tmp_path / "data", port)
    stop_up(second)
    assert (tmp_path / "data" / "canopy.db").is_file()
    assert answer.status_code == 200
    assert [item["scopes"] for item in answer.json()] == [["admin"]]
    assert not any(line.strip().startswith("canopy_") for line in second_lines)


def _worker_of(process: subprocess.Popen[str]) -> int:
    """The pid of the worker `canopy up` started, once it runs."""
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        children = subprocess.run(
            ["ps", "-o", "pid=,args=", "--ppid", str(process.pid)],
            capture_output=True,
            text=True,
            check=False,
        )
        for line in children.stdout.splitlines():
            pid, _, command = line.strip().partition(" ")
            if "-m worker" in command:
                return int(pid)
        time.sleep(0.1)
    raise AssertionError("canopy up started no worker")


def _wait_until_gone(pid: int) -> None:
    deadline = time.monotonic() + 60
    while Path(f"/proc/{pid}").exists() and "zombie" not in Path(f"/proc/{pid}/status").read_text():
        assert time.monotonic() < deadline, f"process {pid} is still running"
        time.sleep(0.1)


STOP_WITHIN_S = 10
"""How long systemd or docker may have to wait for `canopy up` to stop once asked."""


@pytest.mark.parametrize("ending", [signal.SIGINT, signal.SIGTERM])
def test_up_asked_to_stop_stops_its_worker_and_ends_cleanly(tmp_path: Path, ending: signal.Signals) -> None:
    """SIGTERM is how systemd and docker stop it, SIGINT is Ctrl-C: both end it in order, exit 0. Its
    worker's Fatal Python error at shutdown (a thread blocked reading stdin) was 5 of 5 SIGTERMs."""
    port = free_port()
    process, _ = start_up(tmp_path / "data", port)
    worker = _worker_of(process)
    process.send_signal(ending)
    output, _ = process.communicate(timeout=STOP_WITHIN_S)
    _wait_until_gone(worker)
    assert process.returncode == 0, output
    assert "Fatal Python error" not in output and "Traceback" not in output, output
    assert "Finished server process" in output


def test_up_killed_takes_its_worker_with_it(tmp_path: Path) -> None:
    port = free_port()
    process, _ = start_up(tmp_path / "data", port)
    worker = _worker_of(process)
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=60)
    _wait_until_gone(worker)


def test_keys_create_prints_the_key_alone_on_its_last_line_and_list_shows_its_prefix(
    shared_service: Service,
) -> None:
    created = shared_service.canopy(
        "keys", "create", "--scope", "read", "--scope", "capture", "--name", "laptop"
    )
    key = created.stdout.strip().splitlines()[-1]
    listed = shared_service.canopy("keys", "list")
    prefix = key.split("_")[1]
    assert created.returncode == 0
    assert key.startswith(f"canopy_{prefix}_") and " " not in key
    line = next(line for line in listed.stdout.splitlines() if line.startswith(prefix))
    assert "capture read" in line and "laptop" in line


def test_keys_create_refuses_an_unknown_scope(shared_service: Service) -> None:
    refused = shared_service.canopy("keys", "create", "--scope", "root")
    assert refused.returncode == 2
    assert "scopes must be among capture, read, admin" in refused.stderr


def test_revoked_key_stops_working_at_once(shared_service: Service) -> None:
    key = shared_service.create_key("read")
    with shared_service.client(key) as client:
        before = client.get("/v1/orchards")
        revoked = shared_service.canopy("keys", "revoke", key.split("_")[1])
        after = client.get("/v1/orchards")
    assert before.status_code == 200
    assert revoked.returncode == 0
    assert after.status_code == 401


def _keys_create(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """`canopy keys create` run in ``cwd`` with no CANOPY_* setting: only its options and folder count."""
    environment = {name: value for name, value in os.environ.items() if not name.startswith("CANOPY_")}
    return subprocess.run(
        [CANOPY, "keys", "create", *args],
        cwd=cwd,
        env=environment,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_keys_run_from_another_folder_refuse_to_make_a_new_database(
    shared_service: Service, tmp_path: Path
) -> None:
    """Before, `canopy keys create` run elsewhere made ./canopy-data/canopy.db there, and printed a key the
    server refused."""
    refused = _keys_create("--scope", "read", cwd=tmp_path)
    assert refused.returncode == 2
    assert f"no Canopy database at {tmp_path / 'canopy-data' / 'canopy.db'}" in refused.stderr
    assert "--data" in refused.stderr and "--init" in refused.stderr
    assert not (tmp_path / "canopy-data").exists()
    with_data = _keys_create("--scope", "read", "--data", str(shared_service.data_dir), cwd=tmp_path)
    assert with_data.returncode == 0, with_data.stderr
    key = with_data.stdout.strip().splitlines()[-1]
    with shared_service.client(key) as client:
        assert client.get("/v1/orchards").status_code == 200


def test_keys_init_creates_a_new_database_where_asked(tmp_path: Path) -> None:
    made = _keys_create("--scope", "admin", "--data", str(tmp_path / "new"), "--init", cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    assert (tmp_path / "new" / "canopy.db").is_file()


def test_migrations_build_exactly_the_models_schema(tmp_path: Path) -> None:
    database = Database(f"sqlite:///{tmp_path / 'schema.db'}")
    assert not is_current(database)
    upgrade(database)
    with database.read_engine.connect() as connection:
        differences = compare_metadata(MigrationContext.configure(connection), Base.metadata)
    assert is_current(database)
    assert differences == []


@pytest.mark.parametrize("command", [["serve"], ["worker"], ["up"], ["db", "upgrade"]])
def test_a_wrong_setting_stops_the_command_with_one_line_naming_it(
    command: list[str], tmp_path: Path
) -> None:
    environment = {
        **_without_settings(os.environ),
        "CANOPY_DATA_DIR": str(tmp_path / "data"),
        "CANOPY_WORKER_NICE": "99",
        "CANOPY_JOB_LEASE_S": "half a minute",
    }
    done = subprocess.run([CANOPY, *command], env=environment, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert done.stderr.splitlines() == [
        "error: CANOPY_JOB_LEASE_S='half a minute': Input should be a valid number, unable to parse string "
        "as a number; CANOPY_WORKER_NICE='99': Input should be less than or equal to 19"
    ]
    assert not (tmp_path / "data").exists()


def test_a_variable_named_like_a_setting_but_none_is_warned_about(tmp_path: Path) -> None:
    environment = {
        **_without_settings(os.environ),
        "CANOPY_DATA_DIR": str(tmp_path / "data"),
        "CANOPY_JOB_LEASE": "60",  # CANOPY_JOB_LEASE_S meant
        "CANOPY_KEY": "canopy_x",  # the upload client's, and like no setting
    }
    done = subprocess.run(
        [CANOPY, "db", "upgrade"], env=environment, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    assert done.stderr.splitlines() == [
        "CANOPY_JOB_LEASE is no Canopy setting and is ignored; did you mean CANOPY_JOB_LEASE_S?"
    ]


def test_worker_refuses_a_database_that_was_never_migrated(tmp_path: Path) -> None:
    done = subprocess.run(
        [CANOPY, "worker"],
        env={**os.environ, "CANOPY_DATA_DIR": str(tmp_path / "empty")},
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 2
    assert "not initialised" in done.stderr


def test_the_last_admin_key_cannot_be_revoked_over_http_or_on_the_host(service: Service) -> None:
    """Revoking it would lock every user out until someone ran `canopy keys create` on the host."""
    only_admin = service.admin_key.split("_")[1]
    with service.client() as client:
        refused = client.delete(f"/v1/keys/{only_admin}")
        still = client.get("/v1/keys")
    on_host = service.canopy("keys", "revoke", only_admin)
    second = service.create_key("admin")
    with service.client(second) as client:
        revoked = client.delete(f"/v1/keys/{only_admin}")
        last_again = client.delete(f"/v1/keys/{second.split('_')[1]}")
    assert (refused.status_code, refused.json()["code"]) == (409, "last_admin_key")
    assert still.status_code == 200
    assert on_host.returncode == 2 and "last admin key" in on_host.stderr
    assert revoked.status_code == 200 and revoked.json()["revoked_at"] is not None
    assert last_again.status_code == 409


@pytest.mark.parametrize("command", ["up", "serve"])
def test_a_port_in_use_is_said_in_one_line_before_anything_is_created(tmp_path: Path, command: str) -> None:
    """Before, `canopy up` printed a new admin key and then failed, and `./dev.sh run` went on to talk to
    the old server on that port."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        environment = {**os.environ, "CANOPY_DATA_DIR": str(tmp_path / "data")}
        done = subprocess.run(
            [CANOPY, command, "--port", str(port)],
            env=environment,
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"error: cannot listen on 127.0.0.1:{port} (Address already in use): another canopy up or serve "
        "may be running there; stop it or choose another --port"
    ]
    assert "canopy_" not in done.stdout
    assert not (tmp_path / "data" / "canopy.db").exists()


@pytest.mark.parametrize("upgraded_by", ["canopy", "alembic"])
def test_upgrading_a_database_keeps_its_rows_and_never_reuses_an_id(tmp_path: Path, upgraded_by: str) -> None:
    """A database made by the first schema, with a capture deleted, upgraded to the newest by the service
    or by the `alembic` command (alembic.ini, for writing migrations): the rows stay, the tables keep
    AUTOINCREMENT (SQLite alters a table by copying it) and the next id is a new one. Through the `alembic`
    command, the table copies once cascaded every file, job and measurement of a capture away."""
    path = tmp_path / "old.db"
    config = Config()
    config.set_main_option("script_location", str(Path(migrations.__file__).parent))
    with Database(f"sqlite:///{path}").write_engine.connect() as connection:
        config.attributes["connection"] = connection
        command.upgrade(config, "0001")
        connection.commit()
    with sqlite3.connect(path) as old:
        old.execute("INSERT INTO orchards (id, name, created_at) VALUES (1, 'O', '2026-11-01 00:00:00')")
        old.execute("INSERT INTO rows (id, orchard_id, name, created_at) VALUES (1, 1, 'R', '2026-11-01')")
        old.execute("INSERT INTO trees (id, row_id, name, created_at) VALUES (1, 1, 'T', '2026-11-01')")
        for capture_id in (1, 2, 3):
            old.execute(
                "INSERT INTO captures (tree_id, captured_at, manifest, created_at) VALUES (1, ?, '{}', ?)",
                (f"2026-11-0{capture_id} 00:00:00", "2026-11-01 00:00:00"),
            )
        old.execute(
            "INSERT INTO capture_files (capture_id, path, sha256, size_bytes, created_at) "
            "VALUES (1, 'a', 'x', 1, '2026-11-01 00:00:00')"
        )
        old.execute("DELETE FROM captures WHERE id = 3")
    if upgraded_by == "canopy":
        upgrade(Database(f"sqlite:///{path}"))
    else:
        alembic = Path(sys.executable).with_name("alembic")
        environment = {**_without_settings(os.environ), "CANOPY_DATABASE_URL": f"sqlite:///{path}"}
        done = subprocess.run(
            [str(alembic), "upgrade", "head"], cwd=REPOSITORY, env=environment, capture_output=True, text=True
        )
        assert done.returncode == 0, done.stderr
    with sqlite3.connect(path) as new:
        kept = new.execute("SELECT id, created_by_key_id FROM captures ORDER BY id").fetchall()
        new.execute(
            "INSERT INTO captures (tree_id, captured_at, manifest, created_at) VALUES (1, ?, '{}', ?)",
            ("2026-11-09 00:00:00", "2026-11-09 00:00:00"),
        )
        next_id = new.execute("SELECT max(id) FROM captures").fetchone()[0]
        files = new.execute("SELECT capture_id, path FROM capture_files").fetchall()
    assert kept == [(1, None), (2, None)]
    assert files == [(1, "a")]  # owned by no key: open to every capture key, as before
    assert next_id == 4


@pytest.mark.parametrize("ending", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("command", ["serve", "worker"])
def test_serve_and_worker_asked_to_stop_end_in_order(
    tmp_path: Path, command: str, ending: signal.Signals
) -> None:
    """As systemd, docker stop or Ctrl-C would stop them: ended within the time a service manager gives,
    without a traceback or a fatal error (a worker hands a running job back: test_worker.py)."""
    environment = {**os.environ, "CANOPY_DATA_DIR": str(tmp_path / "data")}
    migrated = subprocess.run(
        [CANOPY, "keys", "create", "--scope", "admin", "--init"],
        env=environment,
        capture_output=True,
        check=False,
    )
    assert migrated.returncode == 0, migrated.stderr
    port = free_port()
    arguments = ["serve", "--port", str(port)] if command == "serve" else ["worker"]
    process = subprocess.Popen(
        [CANOPY, *arguments], env=environment, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    assert process.stdout is not None
    ready = "Application startup complete" if command == "serve" else "waiting for jobs"
    lines = []
    while ready not in "".join(lines):
        line = process.stdout.readline()
        assert line, f"canopy {command} ended: {''.join(lines)}"
        lines.append(line)
    process.send_signal(ending)
    output, _ = process.communicate(timeout=STOP_WITHIN_S)
    assert "Traceback" not in output and "Fatal Python error" not in output, output
    assert process.returncode in (0, -ending), output  # serve ends by the signal itself, as uvicorn does


def test_an_upgrade_lets_no_other_land_between_its_migrations(tmp_path: Path) -> None:
    """On SQLite, another process's whole `canopy db upgrade` lands wherever this upgrade takes the write
    lock again after first taking it (to read the version it starts from). The upgrade must hold it to
    the end, or the other would apply the migrations this one goes on to apply again (as three `canopy db
    upgrade` at once did, now and then, on a loaded machine: "duplicate column name"). PostgreSQL
    upgrades take turns on an advisory lock held for the whole upgrade."""
    data = tmp_path / "data"
    ours = Database(f"sqlite:///{data / 'canopy.db'}")
    data.mkdir()
    locked: list[str] = []
    theirs: list[subprocess.CompletedProcess[str]] = []

    def _theirs_lands(_connection: object, _cursor: object, statement: str, *_: object) -> None:
        if statement != "BEGIN IMMEDIATE":
            return
        locked.append(statement)
        if len(locked) > 1:
            theirs.append(
                subprocess.run(
                    [CANOPY, "db", "upgrade"],
                    env={**_without_settings(os.environ), "CANOPY_DATA_DIR": str(data)},
                    capture_output=True,
                    text=True,
                    timeout=60,
                )
            )

    event.listen(ours.write_engine, "before_cursor_execute", _theirs_lands)
    try:
        upgrade(ours)
        assert is_current(ours)
    finally:
        event.remove(ours.write_engine, "before_cursor_execute", _theirs_lands)
        ours.dispose()
    assert locked == ["BEGIN IMMEDIATE"], [run.stderr for run in theirs]


def test_a_migration_that_breaks_a_reference_is_rolled_back_whole(tmp_path: Path) -> None:
    """The foreign keys, off while SQLite's tables are copied, are checked before the upgrade commits: a
    broken reference leaves the schema as it was, and the connection goes back with its foreign keys on."""
    database = Database(f"sqlite:///{tmp_path / 'canopy.db'}")
    try:
        with (
            pytest.raises(RuntimeError, match="references are broken"),
            migration_connection(database) as connection,
        ):
            connection.exec_driver_sql("CREATE TABLE parents (id INTEGER PRIMARY KEY)")
            connection.exec_driver_sql("CREATE TABLE children (parent_id INTEGER REFERENCES parents (id))")
            connection.exec_driver_sql("INSERT INTO children VALUES (7)")
        with database.write_engine.connect() as connection:
            tables = connection.exec_driver_sql("SELECT name FROM sqlite_master WHERE type = 'table'").all()
            foreign_keys = connection.exec_driver_sql("PRAGMA foreign_keys").scalar()
    finally:
        database.dispose()
    assert tables == []
    assert foreign_keys == 1


def _without_settings(environment: Mapping[str, str]) -> dict[str, str]:
    """``environment`` without any ``CANOPY_*`` variable a developer may have set (a database URL)."""
    return {name: value for name, value in environment.items() if not name.startswith("CANOPY_")}


@pytest.mark.parametrize("backend", BACKENDS)
def test_db_upgrade_run_by_three_processes_at_once_leaves_one_current_schema(
    backend: str, tmp_path: Path
) -> None:
    with database_url(backend) as url:
        environment = {**os.environ, "CANOPY_DATA_DIR": str(tmp_path / "data")}
        if url is not None:
            environment["CANOPY_DATABASE_URL"] = url
        runs = [
            subprocess.Popen(
                [CANOPY, "db", "upgrade"],
                env=environment,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
            for _ in range(3)
        ]
        outputs = [run.communicate(timeout=120) for run in runs]
        database = Database(url or f"sqlite:///{tmp_path / 'data' / 'canopy.db'}")
        try:
            assert is_current(database)
        finally:
            database.dispose()
    assert [run.returncode for run in runs] == [0, 0, 0], outputs
    assert {stdout.strip() for stdout, _ in outputs} == {"database at revision 0004"}
