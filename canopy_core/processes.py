"""One step run on each of a capture's views at once, in processes forked from this one.

The per-view steps (a view's ball search above all) are many small numpy calls, which hold the
interpreter's lock between them: threads barely overlap them, processes do. A forked process has the
imports done and the views in memory already; only its results travel back, pickled into an anonymous
file in memory (which, unlike a pipe, takes them whole while this process is still busy with its own
share) and read from there once this process is done.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import mmap
import os
import pickle
import select
import signal
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from threadpoolctl import threadpool_limits

__all__ = ["available_cpus", "cpu_quota", "on_each"]

Item = TypeVar("Item")
Result = TypeVar("Result")


def available_cpus() -> int:
    """How many CPUs this process may use: those it may run on (its affinity, which a cpuset narrows:
    ``docker --cpuset-cpus``), but no more than its CPU quota rounded up (:func:`cpu_quota`: ``docker
    --cpus``, systemd's ``CPUQuota``), since processes beyond the quota only wait for their turn."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    quota = cpu_quota()
    if quota is not None:
        cpus = min(cpus, math.ceil(quota))
    return max(cpus, 1)


def cpu_quota(
    *, root: Path = Path("/sys/fs/cgroup"), membership: Path = Path("/proc/self/cgroup")
) -> float | None:
    """The CPUs' worth of time this process's control groups let it use, the least over its group and the
    groups above it (cgroup v2's ``cpu.max``, v1's ``cpu.cfs_quota_us`` over ``cpu.cfs_period_us``); None
    when none sets one or none can be read (not Linux, no cgroup file system).

    ``membership`` lists the process's groups as ``/proc/self/cgroup`` does, ``root`` is where their
    hierarchies are mounted. A container often sees only its own group, at the mount's root, while its
    membership names the host's path: the groups that do not exist under ``root`` are passed over.
    """
    quotas: list[float | None] = []
    try:
        for line in membership.read_text().splitlines():
            _, controllers, path = line.split(":", 2)
            if controllers == "":  # cgroup v2: one hierarchy, every controller
                quotas += [_v2_quota(group / "cpu.max") for group in _groups(root, path)]
            elif "cpu" in controllers.split(","):
                quotas += [_v1_quota(group) for group in _groups(root / controllers, path)]
    except (OSError, ValueError):  # no such file, a folder not to be looked into, a line not of three fields
        return None
    known = [quota for quota in quotas if quota is not None]
    return min(known) if known else None


def _groups(mount: Path, path: str) -> list[Path]:
    """The existing folders of the group ``path`` and of each group above it, in the hierarchy mounted at
    ``mount`` (the mount itself last)."""
    group = mount / path.lstrip("/")
    return [folder for folder in [group, *group.parents] if folder.is_relative_to(mount) and folder.is_dir()]


def _v2_quota(cpu_max: Path) -> float | None:
    """CPUs' worth of a cgroup v2 ``cpu.max`` ("quota period", or "max period": no limit)."""
    try:
        quota, period = cpu_max.read_text().split()
        return None if quota == "max" else int(quota) / int(period)
    except (OSError, ValueError):
        return None


def _v1_quota(group: Path) -> float | None:
    """CPUs' worth of a cgroup v1 group's CFS quota (-1: no limit)."""
    try:
        quota = int((group / "cpu.cfs_quota_us").read_text())
        period = int((group / "cpu.cfs_period_us").read_text())
    except (OSError, ValueError):
        return None
    return None if quota <= 0 or period <= 0 else quota / period


def on_each(
    function: Callable[[Item], Result], items: Sequence[Item], *, processes: int | None = 1
) -> list[Result]:
    """``[function(item) for item in items]``, with up to ``processes`` of them running at once.

    This process does every ``processes``-th item from the first; each other share runs in a process forked
    for it. ``processes`` 1 (the default, safe in any program) or a system that cannot fork safely (only
    Linux is trusted to) runs everything here, in order; None means one per CPU this process may use
    (:func:`available_cpus`). Either way the linear algebra runs on one thread (see below), so the
    results are the same to the last bit whatever ``processes`` is.

    ``function`` must be deterministic and touch nothing but its item and what it returns: a share whose
    process fails in any way (an exception, a signal, a result that cannot be pickled, a fork or pipe
    refused for want of memory, processes or files, no result after :data:`_STUCK_FACTOR` times this
    process's own share and :data:`_STUCK_GRACE_S` more) is done again here, so that what it raises is
    raised here, as it would have been without processes, and a result is never lost to the way it was
    computed. Where several items raise, the first one's exception is raised, as one at a time would.
    """
    workers = min(len(items), available_cpus() if processes is None else max(processes, 1))
    # One thread for the linear algebra, here and in the forked processes (which inherit the limit): the
    # processes use the cores, and a BLAS library's own threads would only compete with them (a view's
    # ball search took about a tenth longer with two); and the same limit whatever ``processes`` is, since
    # a product split over threads may round differently.
    with threadpool_limits(limits=1, user_api="blas"):
        if workers <= 1 or sys.platform != "linux":
            return [function(item) for item in items]
        return _at_once(function, items, workers)


_STUCK_FACTOR = 10.0
"""A forked share is taken for stuck, killed and done here, when it has not said its results are written
this many times as long after this process finished its own share (or met an item that raised) as that
took (plus :data:`_STUCK_GRACE_S`): the views' shares are alike, and a deadlock in a process forked from a
threaded one is rare but not impossible."""

_STUCK_GRACE_S = 30.0
"""Seconds added to the wait for a forked share, whatever this process's own share took."""

_HELD_SIGNALS = {signal.SIGINT, signal.SIGTERM}
"""Signals held back over a fork: Ctrl-C reaches the whole process group, and the new process must take
it only inside the block that ends in ``os._exit``, never in its caller's code."""

_PR_SET_PDEATHSIG = 1
"""prctl(2)'s option: the signal this process gets when the thread that forked it ends."""

_PRCTL = ctypes.CDLL(None, use_errno=True).prctl if sys.platform == "linux" else None
"""The C library's prctl, looked up once, here, rather than in each forked process."""


_SIZE_BYTES = 8
"""A forked process's last word on its pipe: the size of the pickled results it wrote, little-endian."""


@dataclass
class _Child:
    """A forked process: its id, the read end of the pipe that says when its results are written (and how
    many bytes they take), the anonymous file it writes them to."""

    pid: int
    read_end: int
    results: int


def _at_once(function: Callable[[Item], Result], items: Sequence[Item], workers: int) -> list[Result]:
    """:func:`on_each` with ``workers`` shares, all but the first in forked processes."""
    children: dict[int, _Child | None] = {}
    results: list[Result | None] = [None] * len(items)
    try:
        held = signal.pthread_sigmask(signal.SIG_BLOCK, _HELD_SIGNALS)
        # Held back in this thread, a Ctrl-C cannot leave a child forked but not yet among ``children``.
        # Another thread of this process (a BLAS library's) may still take it and have it raised here; in
        # the few instructions between a fork and its child's entry, that child then works its share and
        # exits unreaped, or dies with this process.
        try:
            for share in range(1, workers):
                children[share] = _fork(function, items[share::workers], mask=held)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, held)
        # The first item that raised, and what it raised: only the items before it still matter.
        started = time.monotonic()
        failed = _in_order(function, items, range(0, len(items), workers), results)
        finished = time.monotonic()
        deadline = finished + _STUCK_FACTOR * (finished - started) + _STUCK_GRACE_S
        for share, child in children.items():
            before = len(items) if failed is None else failed[0]
            if share >= before:
                continue  # all its items come after one that raised
            done: list[Result] | None = _collect(child, deadline)
            if done is not None:
                results[share::workers] = done
                continue
            # Its process failed: done here, in order; an item that raises now comes before ``failed``'s.
            failed = _in_order(function, items, range(share, before, workers), results) or failed
    finally:
        for child in children.values():
            _end(child)
    if failed is not None:
        raise failed[1]
    return results  # type: ignore[return-value]  # every slot filled above


def _in_order(
    function: Callable[[Item], Result], items: Sequence[Item], indices: range, results: list[Result | None]
) -> tuple[int, Exception] | None:
    """Work the ``items`` at ``indices`` here, in order, into ``results``; stop at the first that raises
    and give its index and what it raised (None when none did)."""
    for index in indices:
        try:
            results[index] = function(items[index])
        except Exception as error:
            return index, error
    return None


def _fork(
    function: Callable[[Item], Result], share: Sequence[Item], *, mask: set[int | signal.Signals]
) -> _Child | None:
    """A process forked to work ``function`` on ``share``, write the pickled list of its results to an
    anonymous file and then their size to a pipe (or nothing, when any of it fails); None when no pipe,
    file or process could be made. Called with :data:`_HELD_SIGNALS` blocked; the child sets its signal
    mask back to ``mask`` once it is in the block it cannot leave but by ``os._exit``.

    A pipe alone holds 64 KiB: the child would wait, its results half sent, until this process, done
    with its own share, read them, a round trip between the two for each 64 KiB, and then wait for the
    child to exit. Results of 10 MB (a view's evidence is about 7 MB) took this process 35-40 ms to
    collect that way, here, and take 8 ms from the file.
    """
    parent = os.getpid()
    opened: list[int] = []
    try:
        results = _results_file()
        opened.append(results)
        read_end, write_end = os.pipe()
        opened += [read_end, write_end]
        pid = os.fork()
    except BaseException as error:  # out of files, memory or processes; or a Ctrl-C (see _at_once)
        if os.getpid() != parent:
            os._exit(1)  # a Ctrl-C taken in the new process before its block: never the caller's code
        for descriptor in opened:
            os.close(descriptor)
        if isinstance(error, OSError):
            return None
        raise
    if pid != 0:
        os.close(write_end)
        return _Child(pid, read_end, results)
    # The child: it must never return into the caller's code, whatever happens; os._exit skips the
    # parent's exit handlers and buffered output, which are the parent's to run and write.
    code = 1
    try:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a Ctrl-C held back is taken now, in here
        _die_with(parent)
        os.close(read_end)
        with open(results, "wb", closefd=False) as file:
            pickle.dump([function(item) for item in share], file, protocol=pickle.HIGHEST_PROTOCOL)
            size = file.tell()
        # Fewer bytes than a pipe writes at once, into an empty pipe: written whole, without waiting.
        os.write(write_end, size.to_bytes(_SIZE_BYTES, "little"))
        code = 0
    finally:
        os._exit(code)


def _results_file() -> int:
    """A descriptor of a new anonymous file for a forked process's results: in memory (``memfd_create``)
    where this Python has it (one built against a C library older than glibc 2.27 has not), else an unnamed
    temporary file."""
    if hasattr(os, "memfd_create"):
        return os.memfd_create("canopy-results", os.MFD_CLOEXEC)
    with tempfile.TemporaryFile() as file:
        return os.dup(file.fileno())


def _die_with(parent: int) -> None:
    """Have the kernel kill this process when its parent dies (Linux's ``PR_SET_PDEATHSIG``), and exit at
    once if it is dead already: a measurement the service stops (its timeout, a lost lease) is SIGKILLed,
    and the view it forked must not go on searching for nobody."""
    if _PRCTL is not None:
        _PRCTL(_PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:
        os._exit(1)


def _collect(child: _Child | None, deadline: float) -> list[Any] | None:
    """The results ``child`` wrote, once it has said their size; None when it could not fork, ended
    without saying it (it failed, or was killed), said nothing by ``deadline`` (a ``time.monotonic()``
    time; :func:`_end` then kills it), or what it wrote cannot be read back."""
    if child is None:
        return None
    waiting = select.poll()
    waiting.register(child.read_end, select.POLLIN)
    said = b""
    while len(said) < _SIZE_BYTES:
        remaining_ms = (deadline - time.monotonic()) * 1000.0
        if remaining_ms <= 0 or not waiting.poll(remaining_ms):
            return None  # stuck
        chunk = os.read(child.read_end, _SIZE_BYTES - len(said))
        if not chunk:
            return None  # it ended before its results were written whole
        said += chunk
    try:
        with mmap.mmap(child.results, int.from_bytes(said, "little"), prot=mmap.PROT_READ) as written:
            results: list[Any] = pickle.loads(written)
    except Exception:  # a result that pickles but does not unpickle, or a file cut short: done again here
        return None
    return results


def _end(child: _Child | None) -> None:
    """Close ``child``'s pipe and file and reap it, killing it first if it is still running: exiting, its
    results read, or still at work because this process leaves early (an exception, Ctrl-C, a child taken
    for stuck). A child already reaped by another (this process ignoring SIGCHLD) is passed over."""
    if child is None:
        return
    os.close(child.read_end)
    os.close(child.results)
    with contextlib.suppress(ChildProcessError, ProcessLookupError):
        if os.waitpid(child.pid, os.WNOHANG) == (0, 0):
            os.kill(child.pid, signal.SIGKILL)
            os.waitpid(child.pid, 0)
