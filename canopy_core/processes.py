"""One step run on each of a capture's views at once, in processes forked from this one.

The per-view steps (a view's ball search above all) are many small numpy calls, which hold the
interpreter's lock between them: threads barely overlap them, processes do. A forked process has the
imports done and the views in memory already; only its results travel back, pickled through a pipe.
"""

from __future__ import annotations

import ctypes
import os
import pickle
import signal
import sys
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from threadpoolctl import threadpool_limits

__all__ = ["available_cpus", "on_each"]

Item = TypeVar("Item")
Result = TypeVar("Result")


def available_cpus() -> int:
    """How many CPUs this process may run on (its affinity, which a container's or a job's limit narrows)."""
    if hasattr(os, "sched_getaffinity"):
        return max(len(os.sched_getaffinity(0)), 1)
    return max(os.cpu_count() or 1, 1)


def on_each(
    function: Callable[[Item], Result], items: Sequence[Item], *, processes: int | None = None
) -> list[Result]:
    """``[function(item) for item in items]``, with up to ``processes`` of them running at once.

    This process does every ``processes``-th item from the first; each other share runs in a process forked
    for it. ``processes`` None means one per CPU this process may use (:func:`available_cpus`); 1, or a
    system that cannot fork safely (only Linux is trusted to), runs everything here, in order.

    ``function`` must be deterministic and touch nothing but its item and what it returns: a share whose
    process fails in any way (an exception, a signal, a result that cannot be pickled, a fork refused for
    want of memory or processes) is done again here, so that what it raises is raised here, as it would
    have been without processes, and a result is never lost to the way it was computed.
    """
    count = len(items)
    workers = min(count, available_cpus() if processes is None else max(processes, 1))
    if workers <= 1 or sys.platform != "linux":
        return [function(item) for item in items]
    # One thread each for the linear algebra, here and in the forked processes (which inherit the limit):
    # the processes use the cores, and a BLAS library's own threads would only compete with them (a view's
    # ball search took about a tenth longer with two).
    with threadpool_limits(limits=1, user_api="blas"):
        children = {share: _fork(function, items[share::workers]) for share in range(1, workers)}
        results: list[Result | None] = [None] * count
        try:
            for index in range(0, count, workers):
                results[index] = function(items[index])
            for share, child in children.items():
                done: list[Result] | None = _collect(child)
                if done is None:
                    done = [function(item) for item in items[share::workers]]
                results[share::workers] = done
        finally:
            for child in children.values():
                _end(child)
    return results  # type: ignore[return-value]  # every slot filled above


_PR_SET_PDEATHSIG = 1
"""prctl(2)'s option: the signal this process gets when its parent thread dies."""

_Child = tuple[int, int] | None
"""A forked process's id and the read end of its pipe; None when the fork failed."""


def _fork(function: Callable[[Item], Result], share: Sequence[Item]) -> _Child:
    """A process forked to work ``function`` on ``share`` and send back the pickled list of its results
    (or nothing, when any of it fails); None when no process could be forked."""
    read_end, write_end = os.pipe()
    parent = os.getpid()
    try:
        pid = os.fork()
    except OSError:
        os.close(read_end)
        os.close(write_end)
        return None
    if pid != 0:
        os.close(write_end)
        return pid, read_end
    # The child: it must never return into the caller's code, whatever happens; os._exit skips the
    # parent's exit handlers and buffered output, which are the parent's to run and write.
    code = 1
    try:
        _die_with(parent)
        os.close(read_end)
        payload = pickle.dumps([function(item) for item in share], protocol=pickle.HIGHEST_PROTOCOL)
        with os.fdopen(write_end, "wb") as pipe:
            pipe.write(payload)
        code = 0
    finally:
        os._exit(code)


def _die_with(parent: int) -> None:
    """Have the kernel kill this process when its parent dies (Linux's ``PR_SET_PDEATHSIG``), and exit at
    once if it is dead already: a measurement the service stops (its timeout, a lost lease) is SIGKILLed,
    and the view it forked must not go on searching for nobody."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:
        os._exit(1)


def _collect(child: _Child) -> list[Any] | None:
    """The results ``child`` sent, once it has exited; None when it sent none whole or could not fork."""
    if child is None:
        return None
    pid, read_end = child
    with os.fdopen(read_end, "rb", closefd=False) as pipe:
        payload = pipe.read()
    _, status = os.waitpid(pid, 0)
    if not os.WIFEXITED(status) or os.WEXITSTATUS(status) != 0:
        return None
    try:
        results: list[Any] = pickle.loads(payload)
    except Exception:  # a result that pickles but does not unpickle: done again in this process
        return None
    return results


def _end(child: _Child) -> None:
    """Close ``child``'s pipe and reap it, killing it first if it is still running (this process is
    leaving early: an exception, or Ctrl-C)."""
    if child is None:
        return
    pid, read_end = child
    os.close(read_end)
    try:
        if os.waitpid(pid, os.WNOHANG) == (0, 0):
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
    except ChildProcessError:
        pass  # already reaped by _collect
