"""The block executor: the same results wherever blocks run, nothing lost, nothing left behind.

Everything is real: thread and process pools, a Dask ``LocalCluster`` of two
worker processes on loopback (one per module, shared by the Dask tests), and
subprocesses that are killed with SIGKILL. The functions run on workers are
defined here; pool processes and Dask workers import them from this module
(this module's folder, ``tests/sim/``, is on the ``sys.path`` they inherit from pytest).
"""

from __future__ import annotations

import contextlib
import functools
import os
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from railstop.errors import RailstopError
from railstop.sim.executor import ItemFailedError, describe, execute

pytestmark = [
    pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals and /proc"),
    # Every Dask scheduler serves HTTP (metrics) on 8787 by default; the second one moves aside.
    pytest.mark.filterwarnings("ignore:Port 8787 is already in use:UserWarning"),
]

ITEMS = range(12)
SRC = Path(__file__).resolve().parents[2] / "src"


def seeded_sum(block: int) -> float:
    """A deterministic block: the sum of 20 000 normal draws seeded by the block index."""
    return float(np.random.default_rng([20260807, block]).standard_normal(20_000).sum())


EXPECTED = {k: seeded_sum(k) for k in ITEMS}


def slow_sum_and_pid(block: int) -> tuple[float, int]:
    time.sleep(0.2)
    return seeded_sum(block), os.getpid()


def marked_slow(marks: Path, block: int) -> int:
    """Leave a file saying the block started, then take 0.2 s."""
    (marks / f"{block}-{os.getpid()}").touch()
    time.sleep(0.2)
    return os.getpid()


def fails_on_three(block: int) -> int:
    if block == 3:
        raise ValueError(f"block {block} is cursed")
    return block


def _alive(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie (an orphan's zombie may never be reaped here)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _wait_gone(pids: set[int], within_s: float) -> set[int]:
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.05)
    return {p for p in pids if _alive(p)}


@pytest.fixture(scope="module")
def cluster() -> Iterator[Any]:
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=":0",
    ) as cl:
        yield cl


@pytest.fixture
def admin(cluster: Any) -> Iterator[Any]:
    """A client of our own to look at (and shoot) the cluster's workers; both are back before each test."""
    from distributed import Client

    with Client(cluster.scheduler_address, set_as_default=False) as client:
        client.wait_for_workers(2, timeout=30)
        yield client


MODES = {
    "in-process": {},
    "threads": {"workers": 2},
    "processes": {"workers": 2, "processes": True},
}


@pytest.mark.parametrize("mode", [*MODES, "dask"])
def test_same_results_wherever_blocks_run(mode: str, request: pytest.FixtureRequest) -> None:
    if mode == "dask":
        kwargs: dict[str, Any] = {"scheduler": request.getfixturevalue("cluster").scheduler_address}
    else:
        kwargs = MODES[mode]
    got: dict[int, float] = {}
    for item, result in execute(seeded_sum, ITEMS, **kwargs):
        assert item not in got
        got[item] = result
    assert got == EXPECTED


def test_in_process_runs_in_order() -> None:
    assert [item for item, _ in execute(seeded_sum, ITEMS)] == list(ITEMS)


def test_threads_keep_at_most_workers_blocks_in_flight() -> None:
    import threading

    lock = threading.Lock()
    running = peak = 0

    def fn(k: int) -> int:
        nonlocal running, peak
        with lock:
            running += 1
            peak = max(peak, running)
        time.sleep(0.02)
        with lock:
            running -= 1
        return k * k

    assert dict(execute(fn, range(30), workers=3)) == {k: k * k for k in range(30)}
    assert peak <= 3


@pytest.mark.parametrize("mode", [*MODES, "dask"])
def test_a_failing_block_is_named(mode: str, request: pytest.FixtureRequest) -> None:
    if mode == "dask":
        kwargs: dict[str, Any] = {"scheduler": request.getfixturevalue("cluster").scheduler_address}
    else:
        kwargs = MODES[mode]
    with pytest.raises(ItemFailedError, match=r"^block 3 failed: ValueError: block 3 is cursed$") as info:
        for _ in execute(fails_on_three, range(8), **kwargs):
            pass
    assert info.value.item == 3
    assert isinstance(info.value, RailstopError)
    assert isinstance(info.value.__cause__, ValueError)


def test_processes_need_a_function_they_can_import() -> None:
    with pytest.raises(RailstopError, match="must be a module-level function"):
        next(execute(lambda k: k, ITEMS, workers=2, processes=True))


def test_threads_stop_on_break_and_never_start_the_rest() -> None:
    started: list[int] = []

    def fn(k: int) -> int:
        started.append(k)
        time.sleep(0.1)
        return k

    got = []
    t0 = time.perf_counter()
    with contextlib.closing(execute(fn, range(20), workers=2)) as results:
        for item, _ in results:
            got.append(item)
            if len(got) == 2:
                break
    assert time.perf_counter() - t0 < 1.0  # closing does not wait for the running blocks
    time.sleep(0.3)  # the (at most 2) blocks running at the break finish in the background
    assert len(got) == 2
    assert set(started) <= {0, 1, 2, 3}  # 2 yielded + at most 2 in flight; the other 16 never ran


def test_processes_stop_on_break_and_the_workers_go(tmp_path: Path) -> None:
    fn = functools.partial(marked_slow, tmp_path)
    got = []
    t0 = time.perf_counter()
    with contextlib.closing(execute(fn, range(20), workers=2, processes=True)) as results:
        for item, _ in results:
            got.append(item)
            if len(got) == 2:
                break
    closed_after = time.perf_counter() - t0
    time.sleep(0.3)
    marks = [m.name.split("-") for m in tmp_path.iterdir()]
    assert len(marks) <= 4  # 2 yielded + at most 2 in flight; the other 16 never ran
    workers = {int(pid) for _, pid in marks}
    assert _wait_gone(workers, 2.0) == set()  # the running blocks were stopped, not awaited
    assert closed_after < 10.0  # (includes starting the pool)


def test_dask_stops_on_break_and_cancels_the_rest(cluster: Any, admin: Any, tmp_path: Path) -> None:
    fn = functools.partial(marked_slow, tmp_path)
    got = []
    t0 = time.perf_counter()
    with contextlib.closing(execute(fn, range(20), scheduler=cluster.scheduler_address)) as results:
        for item, _ in results:
            got.append(item)
            if len(got) == 2:
                break
    assert time.perf_counter() - t0 < 5.0
    time.sleep(0.6)
    started = len(list(tmp_path.iterdir()))
    time.sleep(0.6)
    assert len(list(tmp_path.iterdir())) == started  # nothing runs any more
    assert started <= 2 + 4 + 2  # yielded + the window (2 x 2 threads) + what was running
    deadline = time.monotonic() + 5
    while cluster.scheduler.tasks and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not cluster.scheduler.tasks  # cancelled and forgotten by the scheduler


def test_dask_worker_killed_mid_campaign_loses_nothing(cluster: Any, admin: Any) -> None:
    pids = admin.run(os.getpid)  # {worker address: pid}
    victim = 0
    got: dict[int, float] = {}
    after_kill: set[int] = set()
    for item, (total, pid) in execute(slow_sum_and_pid, range(20), scheduler=cluster.scheduler_address):
        assert item not in got  # exactly once
        got[item] = total
        if len(got) == 3:
            # A worker with a block in flight (all of them, in practice): that block must run again.
            busy = [address for address, keys in admin.processing().items() if keys]
            assert busy
            victim = pids[busy[0]]
            os.kill(victim, signal.SIGKILL)
        elif len(got) > 6:
            after_kill.add(pid)
    assert got == {k: seeded_sum(k) for k in range(20)}
    assert victim not in after_kill
    # The nanny restarts the worker: the cluster is whole again for the next test.
    admin.wait_for_workers(2, timeout=30)
    assert victim not in admin.run(os.getpid).values()


def test_losing_the_scheduler_fails_in_one_line() -> None:
    """A scheduler that goes away mid-campaign: a RailstopError at once, not a hang."""
    from distributed import LocalCluster

    cl = LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=":0")
    address = cl.scheduler_address
    got = []
    try:
        with pytest.raises(RailstopError, match=rf"^lost the Dask scheduler {address} ") as info:
            for item, _ in execute(slow_sum_and_pid, range(20), scheduler=address):
                got.append(item)
                if len(got) == 2:
                    t0 = time.perf_counter()
                    cl.close()
    finally:
        cl.close()
    assert time.perf_counter() - t0 < 10
    assert "\n" not in str(info.value)


def test_bad_scheduler_addresses_fail_quickly_in_one_line() -> None:
    for address in ("tcp://127.0.0.1:1", "tcp://127.0.0.1:notaport", "nonsense", "http://127.0.0.1:8786"):
        t0 = time.perf_counter()
        with pytest.raises(RailstopError) as info:
            next(execute(seeded_sum, ITEMS, scheduler=address, connect_timeout=1.0))
        assert time.perf_counter() - t0 < 3.0, address
        message = str(info.value)
        assert message.startswith(f"cannot reach the Dask scheduler {address}: "), message
        assert "\n" not in message
    with pytest.raises(RailstopError, match="empty address"):
        execute(seeded_sum, ITEMS, scheduler=" ")
    with pytest.raises(RailstopError, match="exclude each other"):
        execute(seeded_sum, ITEMS, scheduler="tcp://127.0.0.1:1", processes=True)


def test_bad_scheduler_prints_no_traceback(tmp_path: Path) -> None:
    """Not even at exit: a half-built ``distributed.Client`` prints one from its finaliser."""
    script = tmp_path / "bad.py"
    script.write_text(
        textwrap.dedent(
            """
            import socket, threading
            from railstop.errors import RailstopError
            from railstop.sim.executor import execute

            server = socket.create_server(("127.0.0.1", 0))  # something that is not a scheduler

            def serve():
                while True:
                    conn, _ = server.accept()
                    conn.sendall(b"HTTP/1.1 400 Bad Request\\r\\nContent-Length: 0\\r\\n\\r\\n" * 4)
                    conn.close()

            threading.Thread(target=serve, daemon=True).start()
            junk = "tcp://127.0.0.1:%d" % server.getsockname()[1]
            for address in ("tcp://127.0.0.1:1", junk, "tls://127.0.0.1:1"):
                try:
                    for _ in execute(abs, [1], scheduler=address, connect_timeout=1.0):
                        pass
                except RailstopError as exc:
                    print(exc)
            """
        )
    )
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=60, env=_env()
    )
    assert time.perf_counter() - t0 < 15
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert len(lines) == 3, proc.stdout
    assert all(line.startswith("cannot reach the Dask scheduler ") for line in lines), lines
    assert "Traceback" not in proc.stderr, proc.stderr


def test_describe(cluster: Any, admin: Any) -> None:
    assert describe() == "in process"
    assert describe(workers=2) == "2 threads"
    assert describe(workers=2, processes=True) == "2 processes"
    address = cluster.scheduler_address
    assert describe(scheduler=address) == f"dask {address}: 2 workers, 2 threads"
    with pytest.raises(RailstopError, match=r"^cannot reach the Dask scheduler tcp://127\.0\.0\.1:1: "):
        describe(scheduler="tcp://127.0.0.1:1", connect_timeout=0.5)


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(SRC), env.get("PYTHONPATH", "")])
    return env


def test_process_workers_die_with_their_parent(tmp_path: Path) -> None:
    """``kill -9`` of the main process: the pool's workers go too (Linux PR_SET_PDEATHSIG)."""
    if not sys.platform.startswith("linux"):
        pytest.skip("PR_SET_PDEATHSIG is Linux only")
    script = tmp_path / "parent.py"
    script.write_text(
        textwrap.dedent(
            """
            import os, time
            from railstop.sim.executor import execute

            def pid(k):
                time.sleep(0.2 if k < 4 else 120)  # then sit in a long block
                return os.getpid()

            if __name__ == "__main__":
                seen = set()
                for _, p in execute(pid, range(100), workers=2, processes=True):
                    seen.add(p)
                    if len(seen) == 2:
                        print(*seen, flush=True)
            """
        )
    )
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True, env=_env())
    try:
        assert parent.stdout is not None
        workers = {int(p) for p in parent.stdout.readline().split()}
        assert len(workers) == 2 and all(_alive(p) for p in workers)
        time.sleep(0.5)  # both workers are now inside a 120 s block
    finally:
        parent.kill()
        parent.wait()
    assert _wait_gone(workers, 5.0) == set()
