"""The service's commands: ``serve``, ``worker``, ``up`` (both together: the embedded default), ``keys``,
``db``, ``backup`` and ``restore``. They join the ``canopy`` command through the ``canopy.commands`` entry
point (pyproject.toml), which the core's command line reads; nothing here imports it.

Each needs the service extra (``canopy[service]``) and says so when it is missing; its heavy imports
(FastAPI, SQLAlchemy, uvicorn) happen inside the command, so ``canopy --help`` does not pay for them.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Annotated

import typer

from canopy_core.extras import require_extra

if TYPE_CHECKING:
    from service.context import Context
    from service.settings import Settings

__all__ = ["app"]

app = typer.Typer(rich_markup_mode=None)

HostOpt = Annotated[str, typer.Option(help="Address to listen on.")]
PortOpt = Annotated[int, typer.Option(min=1, max=65535, help="TCP port to listen on.")]
DataOpt = Annotated[
    Path | None, typer.Option("--data", help="Data folder (database and blobs); default $CANOPY_DATA_DIR.")
]

keys_app = typer.Typer(
    help="Create, list and revoke API keys (in the database the settings name).", rich_markup_mode=None
)
app.add_typer(keys_app, name="keys")
db_app = typer.Typer(help="The database's schema (in the database the settings name).", rich_markup_mode=None)
app.add_typer(db_app, name="db")


def _settings(data: Path | None = None) -> Settings:
    """The ``CANOPY_*`` settings (``--data`` over the data folder's); a wrong one ends the command with one
    line naming it (code 2)."""
    from service.settings import SettingsError, load_settings

    try:
        return load_settings(data_dir=data) if data is not None else load_settings()
    except SettingsError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None


def _migrated_context(settings: Settings) -> Context:
    from service.context import Context
    from service.migrate import upgrade

    context = Context.from_settings(settings)
    upgrade(context.database)
    return context


def _keys_context(data: Path | None, *, init: bool = False) -> Context:
    """The migrated context of the database the key commands work on; unless ``init``, the embedded SQLite
    database must exist already: a key made in a new database elsewhere would be refused by the server."""
    settings = _settings(data)
    database = settings.data_dir.resolve() / "canopy.db"
    if settings.database_url is None and not init and not database.is_file():
        where = (
            "--data" if data is not None else "$CANOPY_DATA_DIR" if "CANOPY_DATA_DIR" in os.environ else None
        )
        source = f"from {where}" if where else f"the default ./canopy-data, from {Path.cwd()}"
        typer.echo(
            f"error: no Canopy database at {database} (the data folder {source}). Run this in the folder "
            "`canopy up` runs in, pass --data with the service's data folder, or add --init to create a new, "
            "empty database there",
            err=True,
        )
        raise typer.Exit(2)
    return _migrated_context(settings)


def _require_free_port(host: str, port: int) -> None:
    """Exit with one line (code 2) when ``host:port`` is taken, before anything is created: otherwise the
    server would fail after its first key was printed, and a client would find the old server there."""
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn binds
        try:
            probe.bind((host, port))
        except OSError as exc:
            typer.echo(
                f"error: cannot listen on {host}:{port} ({exc.strerror}): another canopy up or serve may "
                "be running there; stop it or choose another --port",
                err=True,
            )
            raise typer.Exit(2) from exc


def _serve(context: Context, host: str, port: int) -> None:
    import uvicorn

    from service.app import create_app
    from service.http_protocol import ProblemH11Protocol

    uvicorn.run(
        create_app(context),
        host=host,
        port=port,
        log_level="info",
        access_log=False,
        http=ProblemH11Protocol,
        timeout_graceful_shutdown=context.settings.shutdown_grace_s,
    )


@app.command()
def serve(host: HostOpt = "127.0.0.1", port: PortOpt = 8000) -> None:
    """Run the HTTP API alone (start workers with `canopy worker`); migrates the database first."""
    require_extra("service", "serve")
    _require_free_port(host, port)
    _serve(_migrated_context(_settings()), host, port)


@app.command()
def worker() -> None:
    """Run one worker: claims measurement jobs and runs them, until SIGTERM or Ctrl-C."""
    require_extra("service", "worker")
    # The worker is its own program (python -m worker): the service never imports it.
    os.execv(sys.executable, [sys.executable, "-m", "worker"])


class _WorkerProcess:
    """The worker of `canopy up`, started again if it ever dies."""

    def __init__(self, environment: dict[str, str]) -> None:
        self._environment = environment
        self._stopping = threading.Event()
        self._lock = threading.Lock()  # no restart may slip in while stopping
        self._process = self._start()
        threading.Thread(target=self._watch, name="worker-watch", daemon=True).start()

    def _start(self) -> subprocess.Popen[bytes]:
        # The worker stops when its stdin closes, which happens when this process ends, even by SIGKILL.
        return subprocess.Popen(
            [sys.executable, "-m", "worker", "--until-stdin-closes"],
            env=self._environment,
            stdin=subprocess.PIPE,
        )

    def _watch(self) -> None:
        while True:
            code = self._process.wait()
            if self._stopping.wait(1.0):
                return
            with self._lock:
                if self._stopping.is_set():
                    return
                typer.echo(f"worker exited with code {code}; starting it again", err=True)
                self._process = self._start()

    def stop(self) -> None:
        """Stop the worker (it hands a running job back to the queue) and start no other."""
        with self._lock:
            self._stopping.set()
            self._process.terminate()
        try:
            self._process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self._process.kill()


def _stop_on_signal(_signal_number: int, _frame: FrameType | None) -> None:
    """A stop asked for (SIGTERM from systemd or docker stop) is an orderly end: exit 0, as after Ctrl-C."""
    raise SystemExit(0)


@app.command()
def up(host: HostOpt = "127.0.0.1", port: PortOpt = 8000, data: DataOpt = None) -> None:
    """The embedded default: API and one worker on a SQLite file in the data folder (./canopy-data).

    Creates the database on first start, and an admin key, printed once.
    """
    require_extra("service", "up")
    from service.keys.service import create_key, list_keys

    _require_free_port(host, port)
    settings = _settings(data)
    context = _migrated_context(settings)
    with context.database.writing() as session:
        first_key = None if list_keys(session) else create_key(session, name="admin", scopes=["admin"]).key
    if first_key is not None:
        typer.echo("Created the first API key (admin scope). It is shown this once; keep it:")
        typer.echo(f"  {first_key}")
    typer.echo(f"Data in {settings.data_dir.resolve()}; API on http://{host}:{port} (docs at /docs)")
    environment = {**os.environ, "CANOPY_DATA_DIR": str(settings.data_dir.resolve())}
    worker_process = _WorkerProcess(environment)
    # uvicorn shuts down on SIGTERM, then raises the signal again with the handler found before it: this
    # one turns it into SystemExit, so that the worker below is stopped rather than orphaned.
    signal.signal(signal.SIGTERM, _stop_on_signal)
    try:
        _serve(context, host, port)
    finally:
        worker_process.stop()


def _embedded_only(settings: Settings, command: str) -> Settings:
    """``settings`` when they name the embedded default (SQLite and the blob folder); otherwise say what
    backs up the engines they name instead, and exit."""
    if settings.database_url is not None:
        typer.echo(
            f"error: canopy {command} handles the embedded SQLite database; back up PostgreSQL with pg_dump "
            "and pg_restore, and the blobs with a copy of the data folder's blobs/ or of the bucket",
            err=True,
        )
        raise typer.Exit(2)
    if settings.s3_bucket is not None:
        typer.echo(
            f"error: canopy {command} handles the embedded data folder, but the blobs are in bucket "
            f"{settings.s3_bucket}: keep them with the object store's versioning or replication",
            err=True,
        )
        raise typer.Exit(2)
    return settings


@app.command("backup")
def backup_command(
    destination: Annotated[Path, typer.Argument(metavar="DEST", help="Folder to write the backup into.")],
    data: DataOpt = None,
) -> None:
    """Copy the database and the files it refers to into DEST, while the service runs (SQLite only).

    DEST may hold an earlier backup: it is brought up to date, copying only the new files.
    """
    require_extra("service", "backup")
    from service.backup import BackupError, backup

    settings = _embedded_only(_settings(data), "backup")
    try:
        report = backup(settings.data_dir.resolve(), destination)
    except BackupError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    typer.echo(
        f"Backed up {report.captures} captures, {report.files} files and {report.measurements} measurements "
        f"({report.blobs} blobs, {report.blobs_copied} copied now, {report.bytes_copied / 1e6:.1f} MB) into "
        f"{destination}"
    )


@app.command("restore")
def restore_command(
    source: Annotated[Path, typer.Argument(metavar="BACKUP", help="A folder `canopy backup` wrote.")],
    data: DataOpt = None,
) -> None:
    """Bring a backup back into the data folder, which must hold no database yet; every file is checked."""
    require_extra("service", "restore")
    from service.backup import BackupError, restore

    settings = _embedded_only(_settings(data), "restore")
    try:
        report = restore(source, settings.data_dir.resolve())
    except BackupError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    typer.echo(
        f"Restored the backup of {report.taken_at}: {report.captures} captures, {report.files} files and "
        f"{report.measurements} measurements into {settings.data_dir.resolve()}"
    )


@keys_app.command("create")
def keys_create(
    scope: Annotated[list[str], typer.Option("--scope", help="capture, read or admin; repeat for several.")],
    name: Annotated[str, typer.Option(help="Who or what the key is for.")] = "unnamed",
    expires_in: Annotated[
        str | None,
        typer.Option(
            "--expires-in", metavar="LIFETIME", help="Refuse the key after this long: 90d, 12h, 30m."
        ),
    ] = None,
    data: DataOpt = None,
    init: Annotated[
        bool, typer.Option("--init", help="Create the database if the data folder has none yet.")
    ] = False,
) -> None:
    """Create a key; it is printed alone on the last line, and never shown again."""
    require_extra("service", "keys create")
    from service.keys.service import create_key, parse_lifetime
    from service.models import utc_text

    try:
        lifetime = None if expires_in is None else parse_lifetime(expires_in)
    except ValueError as exc:
        typer.echo(f"error: --expires-in: {exc}", err=True)
        raise typer.Exit(2) from exc
    context = _keys_context(data, init=init)
    try:
        with context.database.writing() as session:
            new = create_key(session, name=name, scopes=scope, expires_in=lifetime)
            prefix, scopes, expires_at = new.record.prefix, new.record.scopes, new.record.expires_at
    except ValueError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from exc
    until = "" if expires_at is None else f", valid until {utc_text(expires_at)}"
    typer.echo(f"Created key {prefix} ({scopes}) named {name!r}{until}:", err=True)
    typer.echo(new.key)


@keys_app.command("list")
def keys_list(data: DataOpt = None) -> None:
    """Every key: prefix, scopes, name, created, revoked, expires (UTC)."""
    require_extra("service", "keys list")
    from service.keys.service import list_keys

    context = _keys_context(data)
    with context.database.reading() as session:
        records = list_keys(session)
    typer.echo(f"{'prefix':<10}{'scopes':<22}{'created':<22}{'revoked':<22}{'expires':<22}name")
    for record in records:
        revoked = f"{record.revoked_at:%Y-%m-%d %H:%M:%S}" if record.revoked_at else "-"
        expires = f"{record.expires_at:%Y-%m-%d %H:%M:%S}" if record.expires_at else "-"
        typer.echo(
            f"{record.prefix:<10}{record.scopes:<22}{record.created_at:%Y-%m-%d %H:%M:%S}   "
            f"{revoked:<22}{expires:<22}{record.name}"
        )


@keys_app.command("revoke")
def keys_revoke(
    prefix: Annotated[str, typer.Argument(metavar="PREFIX", help="The key's prefix, as `keys list` shows.")],
    data: DataOpt = None,
) -> None:
    """Revoke a key: it stops working at once."""
    require_extra("service", "keys revoke")
    from service.errors import ServiceError
    from service.keys.service import revoke_key

    context = _keys_context(data)
    try:
        with context.database.writing() as session:
            record = revoke_key(session, prefix=prefix)
    except ServiceError as refused:
        typer.echo(f"error: {refused.detail}", err=True)
        raise typer.Exit(2) from refused
    if record is None:
        typer.echo(f"error: no API key with prefix {prefix!r}", err=True)
        raise typer.Exit(2)
    typer.echo(f"revoked {prefix}")


@app.command("gc")
def gc_command(
    data: DataOpt = None,
    dry_run: Annotated[
        bool, typer.Option("--dry-run", help="Count what would be removed; remove nothing.")
    ] = False,
) -> None:
    """Remove stored files no record names (deleted captures, files whose record never came), last stored
    more than CANOPY_BLOB_GC_GRACE_S ago (an hour); safe while the service runs and uploads arrive."""
    require_extra("service", "gc")
    from service.blob_gc import collect_garbage

    settings = _settings(data)
    context = _migrated_context(settings)
    done = collect_garbage(context.database, context.store, grace_s=settings.blob_gc_grace_s, dry_run=dry_run)
    verb = "would remove" if dry_run else "removed"
    typer.echo(
        f"{done.blobs} blobs: {done.referenced} named by a record, {done.recent} unnamed but stored "
        f"within the grace period, {verb} {done.removed} ({done.bytes_freed / 1e6:.1f} MB freed)"
        + (f"; put back {done.restored} a stopped run had set aside" if done.restored else "")
    )


@db_app.command("upgrade")
def db_upgrade(data: DataOpt = None) -> None:
    """Apply the migrations the database lacks (`serve` and `up` do it too when they start; a worker refuses a
    database that is not current), in one transaction: processes upgrading at once take turns, and a failed
    migration leaves the schema as it was."""
    require_extra("service", "db upgrade")
    from service.migrate import current_revision

    settings = _settings(data)
    context = _migrated_context(settings)
    typer.echo(f"database at revision {current_revision(context.database)}")
