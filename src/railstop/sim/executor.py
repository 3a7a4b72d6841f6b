"""Where the blocks of a campaign run: in this process, in threads, in processes or on a Dask cluster.

A campaign is cut into blocks; each block is a pure function of (campaign,
block index) and its result is written by the caller as soon as it arrives.
:func:`execute` runs ``fn(item)`` for every item and yields ``(item, result)``
as each one finishes, in any order; it is the one place that decides where
``fn`` runs:

``scheduler=None, workers <= 1, processes=False``
    In this process, in order (no pool, plain tracebacks under a debugger).
``scheduler=None, workers > 1, processes=False``
    A thread pool. The engine's compiled kernels release the GIL, so threads
    scale and nothing is pickled.
``processes=True``
    A pool of ``workers`` processes started with ``spawn`` (no ``fork`` of a
    process that already runs threads). ``fn`` and the items must be
    picklable, ``fn`` by reference: a module-level function of an importable
    module (in a script, behind ``if __name__ == "__main__"``). On Linux each
    worker asks the kernel (``prctl(PR_SET_PDEATHSIG, SIGTERM)``) to be sent
    SIGTERM when its parent dies, so a ``kill -9`` of the main process never
    leaves orphaned workers holding pipes; the signal is tied to the *thread*
    that started the worker, which is the thread iterating :func:`execute`.
    Workers ignore SIGINT: Ctrl-C reaches the main process, which stops them.
``scheduler="tcp://HOST:PORT"``
    The Dask scheduler at that address (``dask scheduler`` and ``dask worker``
    started by hand or by a cluster manager; railstop has no scheduler of its
    own). ``fn`` and the items are pickled with cloudpickle and must be
    importable on the workers: the workers need the same railstop (and numpy,
    numba, Python) as this process. ``workers`` is ignored: the cluster's
    threads decide. A worker lost in the middle of a block (killed, out of
    memory, machine gone) is Dask's business: it runs the block again
    elsewhere; a block whose workers keep dying (``distributed.scheduler.
    allowed-failures``, 3 by default) fails with :class:`ItemFailedError`.

In every mode at most a bounded number of items is in flight (``workers`` for
the local pools, twice the cluster's threads for Dask), so results stream and
memory stays bounded however many items there are. Any exception raised by
``fn(item)`` ends the iteration with :class:`ItemFailedError` (a
:class:`~railstop.errors.RailstopError`) naming the item and the cause, the
original exception chained as ``__cause__``. When the consumer stops
iterating (``break``, an exception, Ctrl-C, ``close()``), every item not yet
yielded is abandoned: the ones not started never run, running processes are
terminated and Dask futures cancelled. Threads cannot be stopped: a block
already running in a thread finishes in the background and its result is
dropped. Results already yielded belong to the caller.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import logging
import multiprocessing
import os
import pickle
import re
import reprlib
import signal
import sys
import time
import uuid
from collections.abc import Callable, Generator, Iterable, Iterator
from concurrent.futures import (
    FIRST_COMPLETED,
    Executor,
    Future,
    ProcessPoolExecutor,
    ThreadPoolExecutor,
    wait,
)
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from railstop.errors import RailstopError

T = TypeVar("T")
R = TypeVar("R")

#: Seconds to wait for a Dask scheduler to answer before giving up.
CONNECT_TIMEOUT_S = 5.0

_PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>
_item_repr = reprlib.Repr()
_item_repr.maxstring = 60
_item_repr.maxother = 60


class ItemFailedError(RailstopError):
    """``fn(item)`` raised, or the workers running it kept dying; ``__cause__`` is the original error."""

    def __init__(self, item: object, cause: str) -> None:
        self.item = item
        self.cause = cause
        super().__init__(f"block {_item_repr.repr(item)} failed: {cause}")


def execute(
    fn: Callable[[T], R],
    items: Iterable[T],
    *,
    workers: int = 1,
    scheduler: str | None = None,
    processes: bool = False,
    connect_timeout: float = CONNECT_TIMEOUT_S,
) -> Generator[tuple[T, R], None, None]:
    """Run ``fn(item)`` for every item; yield ``(item, result)`` as each finishes (any order).

    See the module docstring for where ``fn`` runs. Raises :class:`RailstopError`
    when the scheduler cannot be reached (within ``connect_timeout`` seconds),
    :class:`ItemFailedError` when an item fails. Nothing starts before the
    first ``next()``: the pool or the connection lives as long as the iteration.
    """
    _check(scheduler, processes)
    if scheduler is not None:
        return _dask(fn, items, scheduler, connect_timeout)
    if processes:
        return _processes(fn, items, max(workers, 1))
    if workers > 1:
        return _threads(fn, items, workers)
    return _in_process(fn, items)


def blocks(first: int, end: int, parts: int, most: int) -> Iterator[tuple[int, int]]:
    """Runs ``first .. end - 1`` cut into consecutive ``(a, b)`` blocks: at least ``parts`` of them
    (so that that many workers are busy) where there are runs enough, each at most ``most`` runs."""
    size = max(1, min(most, -(-(end - first) // max(1, parts))))
    for a in range(first, end, size):
        yield a, min(a + size, end)


def describe(
    workers: int = 1,
    scheduler: str | None = None,
    processes: bool = False,
    *,
    connect_timeout: float = CONNECT_TIMEOUT_S,
) -> str:
    """A label for progress output: ``"2 threads"``, ``"dask tcp://h:8786: 4 workers, 8 threads"``.

    With a scheduler this asks it for its workers, so it doubles as an early
    check of the address (:class:`RailstopError` if it cannot be reached).
    """
    _check(scheduler, processes)
    if scheduler is not None:
        info = _probe_scheduler(scheduler, connect_timeout)
        workers_info = info.get("workers") or {}
        threads = sum(int(w.get("nthreads", 0)) for w in workers_info.values())
        return f"dask {scheduler}: {_plural(len(workers_info), 'worker')}, {_plural(threads, 'thread')}"
    if processes:
        return _plural(max(workers, 1), "process")
    if workers > 1:
        return _plural(workers, "thread")
    return "in process"


def _plural(n: int, word: str) -> str:
    if n == 1:
        return f"1 {word}"
    return f"{n} {word}es" if word.endswith("s") else f"{n} {word}s"


def _check(scheduler: str | None, processes: bool) -> None:
    if scheduler is not None and processes:
        raise RailstopError("--scheduler and --processes exclude each other (Dask workers are processes)")
    if scheduler is not None and not scheduler.strip():
        raise RailstopError("--scheduler: empty address (expected tcp://HOST:PORT)")


def _fn_failed(item: object, exc: BaseException) -> ItemFailedError:
    if isinstance(exc, BrokenProcessPool):
        cause = "a worker process died abruptly (killed by a signal, or out of memory)"
    else:
        text = str(exc).strip().splitlines()
        if isinstance(exc, RailstopError) and text:
            cause = text[0]  # a railstop error is its message, written for the user
        else:
            cause = f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__
    error = ItemFailedError(item, cause)
    error.__cause__ = exc
    return error


# --------------------------------------------------------------------------- local


def _in_process(fn: Callable[[T], R], items: Iterable[T]) -> Generator[tuple[T, R], None, None]:
    for item in items:
        try:
            result = fn(item)
        except Exception as exc:
            raise _fn_failed(item, exc) from exc
        yield item, result


def _threads(fn: Callable[[T], R], items: Iterable[T], workers: int) -> Generator[tuple[T, R], None, None]:
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="railstop-block")
    finished = False
    try:
        yield from _pooled(pool, fn, items, workers)
        finished = True
    finally:
        # Interrupted: queued items are cancelled; a running thread cannot be
        # stopped, it finishes in the background and its result is dropped.
        pool.shutdown(wait=finished, cancel_futures=True)


def _processes(fn: Callable[[T], R], items: Iterable[T], workers: int) -> Generator[tuple[T, R], None, None]:
    try:
        pickle.dumps(fn)
    except Exception as exc:
        raise RailstopError(
            f"cannot send {fn!r} to worker processes ({type(exc).__name__}: {exc}); "
            "it must be a module-level function (or a functools.partial of one)"
        ) from None
    pool = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_worker_init,
        initargs=(os.getpid(),),
    )
    finished = False
    try:
        yield from _pooled(pool, fn, items, workers)
        finished = True
    finally:
        if finished:
            pool.shutdown(wait=True)
        else:
            # The results of the running items would be dropped: stop them now
            # (``terminate_workers`` is Python 3.14+; before, the pool's own list).
            procs = list((getattr(pool, "_processes", None) or {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            terminate = getattr(pool, "terminate_workers", None)
            if terminate is not None:
                with contextlib.suppress(Exception):
                    terminate()
            for proc in procs:
                with contextlib.suppress(Exception):
                    proc.terminate()
            for proc in procs:
                with contextlib.suppress(Exception):
                    proc.join(timeout=5)


def _worker_init(parent_pid: int) -> None:
    """In each pool process: die with the parent (Linux), leave Ctrl-C to the parent."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        except (OSError, AttributeError):  # no prctl: an orphan exits when its pipe closes
            pass
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)


def _pooled(
    pool: Executor, fn: Callable[[T], R], items: Iterable[T], limit: int
) -> Generator[tuple[T, R], None, None]:
    """Feed ``pool`` with at most ``limit`` items in flight; yield results as they finish."""
    source = iter(items)
    pending: dict[Future[R], T] = {}

    def top_up() -> None:
        while len(pending) < limit:
            try:
                item = next(source)
            except StopIteration:
                return
            pending[pool.submit(fn, item)] = item

    try:
        top_up()
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                item = pending.pop(fut)
                try:
                    result = fut.result()
                except Exception as exc:
                    raise _fn_failed(item, exc) from exc
                top_up()  # keep the pool busy while the caller handles the result
                yield item, result
    finally:
        for fut in pending:
            fut.cancel()


# --------------------------------------------------------------------------- Dask


def _import_distributed() -> Any:
    # Lazy (start-up, and optional): Dask is loaded only for --scheduler, and may not be installed.
    try:
        import distributed
    except ImportError:
        raise RailstopError(
            "--scheduler needs Dask's distributed scheduler: pip install 'dask[distributed]'"
        ) from None
    return distributed


def _unreachable(address: str, exc: BaseException) -> RailstopError:
    if isinstance(exc, (TimeoutError, asyncio.TimeoutError)) and not str(exc):
        reason = "no answer"
    elif isinstance(exc, (OSError, ValueError, TypeError)):
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        cause = exc.__cause__
        if cause is not None and str(cause):
            # "in <distributed.comm.tcp.TCPConnector object at 0x...>: ConnectionRefusedError: ..."
            reason += f" ({_comm_text(cause)})"
    else:
        reason = f"the service there does not answer as a Dask scheduler ({type(exc).__name__})"
    return RailstopError(f"cannot reach the Dask scheduler {address}: {reason}")


def _comm_text(exc: BaseException) -> str:
    """One line about a comm error, without Dask's ``in <TCP ... object at 0x...>:`` prefix."""
    lines = str(exc).strip().splitlines()
    return re.sub(r"^in <[^>]*>: ", "", lines[0]) if lines else type(exc).__name__


def _lost(address: str, detail: str) -> RailstopError:
    return RailstopError(f"lost the Dask scheduler {address} (it stopped, or the network failed): {detail}")


def _probe_scheduler(address: str, timeout: float) -> dict[str, Any]:
    """Ask the scheduler at ``address`` who it is; RailstopError if it does not answer as one.

    A plain ``Client(address)`` on a bad address can fail slowly, with odd
    errors, and leave a half-built client whose finaliser prints a traceback;
    this probe is one connection with a deadline.
    """
    distributed = _import_distributed()
    from distributed.comm.core import connect  # lazy: see _import_distributed

    async def probe() -> Any:
        args = distributed.Security().get_connection_args("client")
        comm = await connect(address, timeout=timeout, **args)  # type: ignore[no-untyped-call,unused-ignore]
        try:
            await comm.write({"op": "identity"})
            return await comm.read()
        finally:
            await comm.close()

    def run() -> Any:
        return asyncio.run(asyncio.wait_for(probe(), timeout + 1.0))

    # In a thread of its own: the caller may itself be inside an event loop.
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="railstop-dask-probe") as one:
        try:
            info = one.submit(run).result()
        except Exception as exc:
            raise _unreachable(address, exc) from None
    if not isinstance(info, dict) or info.get("type") != "Scheduler":
        kind = info.get("type") if isinstance(info, dict) else type(info).__name__
        raise RailstopError(f"cannot reach the Dask scheduler {address}: the service there is a {kind}")
    return info


def _dask(
    fn: Callable[[T], R], items: Iterable[T], address: str, timeout: float
) -> Generator[tuple[T, R], None, None]:
    distributed = _import_distributed()
    from dask.utils import funcname  # lazy: see _import_distributed
    from distributed.comm.core import CommClosedError  # lazy: see _import_distributed

    _probe_scheduler(address, timeout)
    try:
        client = distributed.Client(address, timeout=timeout, set_as_default=False)
    except Exception as exc:
        raise _unreachable(address, exc) from None

    prefix = f"{funcname(fn)}-{uuid.uuid4().hex[:8]}"
    source = iter(enumerate(items))
    pending: dict[str, tuple[Any, T]] = {}  # key -> (future, item)
    completed = distributed.as_completed(loop=client.loop)
    window = 2
    window_at = float("-inf")

    def top_up() -> None:
        nonlocal window, window_at
        if time.monotonic() - window_at > 2.0:  # the cluster can grow or shrink
            window = max(2 * sum(client.nthreads().values()), 2)
            window_at = time.monotonic()
        while len(pending) < window:
            try:
                index, item = next(source)
            except StopIteration:
                return
            future = client.submit(fn, item, key=f"{prefix}-{index}", pure=False)
            pending[future.key] = (future, item)
            completed.add(future)

    try:
        top_up()
        for future in completed:
            _, item = pending.pop(future.key)
            if client.status != "running":
                raise _lost(address, f"block {_item_repr.repr(item)} was cancelled")
            if future.status == "cancelled":
                raise ItemFailedError(item, f"cancelled on the Dask cluster {address} (by another client?)")
            try:
                # A result lost with its worker after completion is recomputed; this waits for it.
                result = future.result()
            except Exception as exc:
                if isinstance(exc, CommClosedError) or client.status != "running":
                    raise _lost(address, _comm_text(exc)) from exc
                raise _fn_failed(item, exc) from exc
            del future
            top_up()
            yield item, result
    finally:
        completed.clear()
        outstanding = [f for f, _ in pending.values()]
        pending.clear()
        lost = client.status != "running"
        with contextlib.suppress(Exception):
            if outstanding and not lost:
                client.cancel(outstanding, force=True)
        del outstanding
        # With the scheduler gone, closing cancels the client's reconnection
        # attempts, which Dask logs as an error with a traceback: the loss has
        # already been reported in one line.
        client_log = logging.getLogger("distributed.client")
        was_disabled = client_log.disabled
        client_log.disabled = was_disabled or lost
        try:
            with contextlib.suppress(Exception):
                client.close()
        finally:
            client_log.disabled = was_disabled
