"""Per-view steps run at once in forked processes: the same results in the same order as one at a time,
whatever happens to a process, and no process left behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from canopy_core import processes
from canopy_core.processes import on_each

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="views run in forked processes on Linux only")


def _square_and_where(item: int) -> tuple[int, int]:
    return item * item, os.getpid()


def test_results_come_back_in_order_and_other_processes_did_a_share() -> None:
    results = on_each(_square_and_where, list(range(7)), processes=3)
    assert [value for value, _ in results] == [i * i for i in range(7)]
    workers = [pid for _, pid in results]
    assert workers[0::3] == [os.getpid()] * 3  # this process does every third item from the first
    assert os.getpid() not in workers[1::3] + workers[2::3]
    assert len(set(workers)) == 3


def test_one_process_the_default_runs_everything_here() -> None:
    assert {pid for _, pid in on_each(_square_and_where, [1, 2, 3])} == {os.getpid()}
    assert {pid for _, pid in on_each(_square_and_where, [1, 2, 3], processes=1)} == {os.getpid()}


def test_a_fork_refused_leaves_its_share_to_this_process(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse() -> int:
        raise BlockingIOError("Resource temporarily unavailable")  # as fork(2) says at a process limit

    monkeypatch.setattr(os, "fork", refuse)
    assert on_each(_square_and_where, [1, 2, 3], processes=2) == [(i * i, os.getpid()) for i in (1, 2, 3)]


def test_a_share_stuck_past_its_deadline_is_killed_and_done_here(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setattr(processes, "_STUCK_GRACE_S", 1.0)
    parent = os.getpid()
    pid_file = tmp_path / "child.pid"

    def stick_unless_parent(item: int) -> tuple[int, int]:
        if os.getpid() != parent:
            _write_pid(pid_file)
            time.sleep(600)
        return _square_and_where(item)

    assert on_each(stick_unless_parent, [1, 2], processes=2) == [(1, parent), (4, parent)]
    assert not _running(int(pid_file.read_text()))


def _refuse_three(item: int) -> int:
    if item == 3:
        raise ValueError(f"item {item} is refused")
    return item


def test_an_error_in_another_process_is_raised_here_as_it_was_raised_there() -> None:
    with pytest.raises(ValueError, match="item 3 is refused"):
        on_each(_refuse_three, [0, 1, 2, 3], processes=2)


def _refuse_one_and_two(item: int) -> int:
    if item in (1, 2):
        raise ValueError(f"item {item} is refused")
    return item


def test_of_several_items_that_raise_the_first_one_s_error_is_raised_as_one_at_a_time_would() -> None:
    # This process meets item 2 first; item 1, in the other process, comes before it.
    with pytest.raises(ValueError, match="item 1 is refused"):
        on_each(_refuse_one_and_two, [0, 1, 2, 3], processes=2)
    with pytest.raises(ValueError, match="item 1 is refused"):
        on_each(_refuse_one_and_two, [0, 1, 2, 3, 4, 5], processes=3)


def test_a_share_all_after_an_item_that_raised_is_not_waited_for(tmp_path: Path) -> None:
    parent = os.getpid()
    pid_file = tmp_path / "child.pid"

    def refuse_one_linger_on_two(item: int) -> int:
        if item == 1:
            raise ValueError("item 1 is refused")  # in its process, then again here
        if item == 2 and os.getpid() != parent:
            _write_pid(pid_file)
            time.sleep(60)
        _wait_for(pid_file)  # item 0, here: the process of item 2 has started
        return item

    started = time.monotonic()
    with pytest.raises(ValueError, match="item 1 is refused"):
        on_each(refuse_one_linger_on_two, [0, 1, 2], processes=3)
    assert time.monotonic() - started < 30.0  # not the minute item 2 takes: its error could not come first
    assert not _running(int(pid_file.read_text()))


def test_results_larger_than_a_pipe_holds_come_back_whole_without_the_other_process_waiting_to_send_them(
    tmp_path: Path,
) -> None:
    parent = os.getpid()
    pid_file = tmp_path / "child.pid"

    def eight_megabytes(item: int) -> tuple[int, np.ndarray]:
        if os.getpid() != parent:
            _write_pid(pid_file)
        else:  # the other process ends, its results written, while this one is still at its own share
            _wait_for(pid_file)
            other = int(pid_file.read_text())
            deadline = time.monotonic() + 30
            while _running(other):
                assert time.monotonic() < deadline, "the other process waits for this one to take its results"
                time.sleep(0.02)
        return os.getpid(), np.full(1_000_000, float(item))

    results = on_each(eight_megabytes, [1, 2], processes=2)
    # Item 2's result is the other process's, not worked out again here after a failure to take it.
    assert [worker for worker, _ in results] == [parent, int(pid_file.read_text())]
    assert [result.shape for _, result in results] == [(1_000_000,)] * 2
    assert [set(result.tolist()) for _, result in results] == [{1.0}, {2.0}]


def test_without_memfd_create_the_results_come_back_through_a_temporary_file(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delattr(os, "memfd_create")  # a Python built against a C library older than glibc 2.27
    results = on_each(_square_and_where, [1, 2, 3, 4], processes=2)
    assert [value for value, _ in results] == [1, 4, 9, 16]
    assert [pid for _, pid in results][0::2] == [os.getpid()] * 2
    assert os.getpid() not in [pid for _, pid in results][1::2]


def test_a_share_whose_process_is_killed_is_done_again_here() -> None:
    parent = os.getpid()

    def die_unless_parent(item: int) -> tuple[int, int]:
        if os.getpid() != parent:
            os.kill(os.getpid(), signal.SIGKILL)
        return _square_and_where(item)

    results = on_each(die_unless_parent, [1, 2, 3, 4], processes=2)
    assert results == [(1, parent), (4, parent), (9, parent), (16, parent)]


def test_a_result_that_cannot_be_pickled_is_worked_out_here() -> None:
    parent = os.getpid()
    results = on_each(lambda item: (lambda: item, os.getpid()), [5, 6], processes=2)
    assert [make() for make, _ in results] == [5, 6]
    assert [pid for _, pid in results] == [parent, parent]


def test_a_process_still_running_when_this_one_fails_is_killed_and_reaped(tmp_path: Path) -> None:
    parent = os.getpid()
    pid_file = tmp_path / "child.pid"

    def fail_here_linger_there(item: int) -> int:
        if os.getpid() == parent:
            _wait_for(pid_file)  # the other share has started
            raise RuntimeError("this process's share failed")
        _write_pid(pid_file)
        time.sleep(60)
        return item

    with pytest.raises(RuntimeError, match="this process's share failed"):
        on_each(fail_here_linger_there, [0, 1], processes=2)
    with pytest.raises(ProcessLookupError):  # killed and reaped: not even a zombie is left
        os.kill(int(pid_file.read_text()), 0)


_LINGERING_PARENT = """
import os, sys, time
from pathlib import Path
from canopy_core import processes
from canopy_core.processes import on_each

pid_file = Path(sys.argv[1])
parent = os.getpid()

def linger(item: int) -> int:
    if os.getpid() != parent:
        pid_file.with_suffix(".tmp").write_text(str(os.getpid()))
        pid_file.with_suffix(".tmp").replace(pid_file)
    time.sleep(60)
    return item

on_each(linger, [0, 1], processes=2)
"""


def test_a_process_whose_parent_is_killed_dies_with_it(tmp_path: Path) -> None:
    pid_file = tmp_path / "child.pid"
    parent = subprocess.Popen([sys.executable, "-c", _LINGERING_PARENT, str(pid_file)])
    try:
        _wait_for(pid_file)
    finally:
        parent.kill()  # as the worker stops a measurement: SIGKILL, which no handler sees
        parent.wait()
    child = int(pid_file.read_text())
    deadline = time.monotonic() + 10
    while _running(child):
        assert time.monotonic() < deadline, f"process {child} outlived its killed parent"
        time.sleep(0.05)


def _running(pid: int) -> bool:
    """Whether ``pid`` is a live process (not gone, not a zombie waiting for a reaper)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


def _write_pid(pid_file: Path) -> None:
    """Write this process's id to ``pid_file`` whole (written beside it, then renamed)."""
    pid_file.with_suffix(".tmp").write_text(str(os.getpid()))
    pid_file.with_suffix(".tmp").replace(pid_file)


def _wait_for(pid_file: Path) -> None:
    """Wait until ``pid_file`` exists; fail after a minute rather than hang the suite."""
    deadline = time.monotonic() + 60
    while not pid_file.exists():
        assert time.monotonic() < deadline, f"no process wrote {pid_file.name} within a minute"
        time.sleep(0.02)


def _group(folder: Path, **files: str) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (folder / name.replace("__", ".")).write_text(text)


def test_a_cpu_quota_is_read_from_the_group_and_those_above_it_the_least_counting(tmp_path: Path) -> None:
    root = tmp_path / "cgroup"
    _group(root, cpu__max="max 100000\n")
    _group(root / "machine" / "job", cpu__max="150000 100000\n")
    _group(root / "machine", cpu__max="300000 100000\n")
    membership = tmp_path / "membership"
    membership.write_text("0::/machine/job\n")
    assert processes.cpu_quota(root=root, membership=membership) == 1.5
    membership.write_text("0::/\n")  # a container's own group at the mount's root: no limit there
    assert processes.cpu_quota(root=root, membership=membership) is None


def test_a_cgroup_v1_quota_counts_and_a_group_not_mounted_here_is_passed_over(tmp_path: Path) -> None:
    root = tmp_path / "cgroup"
    _group(root / "cpu,cpuacct", cpu__cfs_quota_us="50000\n", cpu__cfs_period_us="100000\n")
    membership = tmp_path / "membership"
    membership.write_text("4:memory:/docker/abc\n3:cpu,cpuacct:/docker/abc\n")  # the host's path
    assert processes.cpu_quota(root=root, membership=membership) == 0.5
    _group(root / "cpu,cpuacct", cpu__cfs_quota_us="-1\n")
    assert processes.cpu_quota(root=root, membership=membership) is None
    assert processes.cpu_quota(root=root, membership=tmp_path / "absent") is None


def test_no_more_processes_than_the_cpu_quota_allows(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(processes, "cpu_quota", lambda: 0.5)
    assert processes.available_cpus() == 1
    results = on_each(_square_and_where, list(range(4)), processes=None)
    assert [pid for _, pid in results] == [os.getpid()] * 4  # a quota of half a CPU: all done here
