"""A warm ``python -m railstop.cli`` for the tests that run the command hundreds of times.

Each ``python -m railstop.cli`` pays about 0.8 s of CPU to import numpy, numba, pydantic, typer
and rich before it reads its first argument; the bad-input sweep alone runs it 270 times. A
zygote is a helper process that imports all that once, loads the compiled stop model, and then
*forks* a child for each command. The child is a real process of its own (its own pid, working
folder, environment, file descriptors and exit code), it runs the module as ``python -m`` would
(``runpy``, ``__main__``), ends as an interpreter ends (non-daemon threads joined, ``atexit``
handlers run, output flushed) and the test reads its exit code, stdout and stderr as from
``subprocess.run``.

What it does not reproduce: anything the package reads from the environment at import (the
zygote imports with the environment it was started with). Tests that change ``COLUMNS``, the cache
folders or similar keep a fresh interpreter (``subprocess``).

The zygote is single-threaded, so forking it is safe; it talks to the test over its stdin and
stdout, one JSON object per line.
"""

from __future__ import annotations

import atexit
import io
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

#: What the zygote imports (and loads) before it forks: the command, the modules its commands
#: import when they run, and the compiled stop model.
PRELOAD = (
    "railstop.cli",
    "railstop.config.plausibility",
    "railstop.sim.campaign",
    "railstop.sim.single",
    "railstop.sim.line",
    "railstop.sim.certify",
    "railstop.report.campaign_report",
    "railstop.store",  # SQLAlchemy: about a second of every command that writes its database
    "scipy.special",  # the bounds' quantiles (imported when a campaign sums up)
)


class Zygote:
    """The test's side: start the zygote, run commands through it, stop it."""

    def __init__(self, env: Mapping[str, str]) -> None:
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "zygote"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env={
                **env,
                "PYTHONPATH": os.pathsep.join([str(Path(__file__).parent), env.get("PYTHONPATH", "")]),
            },
        )
        ready = self._proc.stdout.readline() if self._proc.stdout else ""
        if ready.strip() != "ready":
            raise RuntimeError(f"the zygote did not start: {ready!r}")

    def run(
        self,
        module: str,
        argv: Sequence[str],
        *,
        cwd: Path,
        env: Mapping[str, str],
        timeout_s: float,
    ) -> tuple[int | None, str, str]:
        """(exit code, None when it timed out; stdout; stderr) of ``python -m module *argv``."""
        request = {"module": module, "argv": list(argv), "cwd": str(cwd), "env": dict(env)}
        reply = self._ask({**request, "timeout": timeout_s})
        return reply["rc"], reply["stdout"], reply["stderr"]

    def _ask(self, request: dict[str, Any]) -> dict[str, Any]:
        assert self._proc.stdin is not None and self._proc.stdout is not None
        self._proc.stdin.write(json.dumps(request) + "\n")
        self._proc.stdin.flush()
        reply: dict[str, Any] = json.loads(self._proc.stdout.readline())
        return reply

    def spawn(self, module: str, argv: Sequence[str], *, env: Mapping[str, str]) -> ZygoteProcess:
        """``subprocess.Popen([python, -m, module, *argv], stdout=PIPE, stderr=PIPE, text=True)``
        forked from the zygote (the child's output comes through two named pipes)."""
        folder = Path(tempfile.mkdtemp(prefix="zygote-"))
        fifos = (folder / "stdout", folder / "stderr")
        for fifo in fifos:
            os.mkfifo(fifo)
        request = {"spawn": True, "module": module, "argv": list(argv), "cwd": os.getcwd(), "env": dict(env)}
        reply = self._ask({**request, "fifos": [str(f) for f in fifos]})
        # The child opens the pipes in this order; opening the reading ends meets it.
        out = open(fifos[0], encoding="utf-8", errors="replace")  # noqa: SIM115 - the process holds it
        err = open(fifos[1], encoding="utf-8", errors="replace")  # noqa: SIM115
        for fifo in fifos:
            fifo.unlink()
        folder.rmdir()
        return ZygoteProcess(self, int(reply["pid"]), [sys.executable, "-m", module, *argv], out, err)

    def status(self, pid: int) -> int | None:
        """The exit code of a spawned child (None while it runs)."""
        rc: int | None = self._ask({"status": pid})["rc"]
        return rc

    def close(self) -> None:
        if self._proc.stdin is not None:
            self._proc.stdin.close()
        try:
            self._proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()


class ZygoteProcess:
    """The part of ``subprocess.Popen`` the live tests use, for a child forked by the zygote."""

    def __init__(self, zygote: Zygote, pid: int, args: list[str], stdout: Any, stderr: Any) -> None:
        self._zygote = zygote
        self.pid = pid
        self.args = args
        self.stdout = stdout
        self.stderr = stderr
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            self.returncode = self._zygote.status(self.pid)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        end = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if end is not None and time.monotonic() > end:
                raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
            time.sleep(0.01)
        assert self.returncode is not None
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            os.kill(self.pid, sig)

    def kill(self) -> None:
        self.send_signal(9)

    def communicate(self, timeout: float | None = None) -> tuple[str, str]:
        """Read both outputs to their end (on threads, as Popen does), then wait for the exit."""
        import threading

        texts: dict[str, str] = {}

        def drain(name: str, stream: Any) -> None:
            texts[name] = stream.read() if stream is not None and not stream.closed else ""

        threads = [
            threading.Thread(target=drain, args=(name, stream), daemon=True)
            for name, stream in (("out", self.stdout), ("err", self.stderr))
        ]
        for t in threads:
            t.start()
        end = None if timeout is None else time.monotonic() + timeout
        for t in threads:
            t.join(None if end is None else max(end - time.monotonic(), 0.0))
            if t.is_alive():
                raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
        self.wait(None if end is None else max(end - time.monotonic(), 0.1))
        for stream in (self.stdout, self.stderr):
            stream.close()
        return texts.get("out", ""), texts.get("err", "")


def popen_cli(
    *args: str, env: Mapping[str, str] | None = None, module: str = "railstop.cli"
) -> ZygoteProcess:
    """``subprocess.Popen([python, -m, module, *args], stdout=PIPE, stderr=PIPE, text=True,
    env=env)``, forked from a warm zygote of this test process."""
    env = dict(os.environ if env is None else env)
    return shared(env).spawn(module, args, env=env)


#: What the package (or rich, typer, numba) reads from the environment when it is imported: a
#: command run with other values than a zygote's gets a zygote of its own.
IMPORT_ENV = ("COLUMNS", "LINES", "NO_COLOR", "FORCE_COLOR", "TERM", "RAILSTOP_CACHE_DIR", "XDG_CACHE_HOME")

_SHARED: dict[tuple[str | None, ...], Zygote] = {}


def shared(env: Mapping[str, str]) -> Zygote:
    """This test process's zygote for ``env``'s import-time values (started on first use)."""
    key = tuple(env.get(name) for name in IMPORT_ENV)
    zygote = _SHARED.get(key)
    if zygote is None:
        zygote = _SHARED[key] = Zygote(env)
        atexit.register(zygote.close)
    return zygote


def run_cli(
    *args: str,
    cwd: Path | None = None,
    env: Mapping[str, str] | None = None,
    timeout: float = 300.0,
    module: str = "railstop.cli",
) -> subprocess.CompletedProcess[str]:
    """``subprocess.run([python, -m, module, *args], capture_output=True, text=True)``, forked
    from a warm zygote of this test process (one per distinct import-time environment)."""
    env = dict(os.environ if env is None else env)
    zygote = shared(env)
    argv = [sys.executable, "-m", module, *args]
    rc, out, err = zygote.run(module, args, cwd=cwd or Path.cwd(), env=env, timeout_s=timeout)
    if rc is None:
        raise subprocess.TimeoutExpired(argv, timeout, out, err)
    return subprocess.CompletedProcess(argv, rc, out, err)


# ---------------------------------------------------------------------- the zygote itself


def _child(request: dict[str, Any], out_fd: int, err_fd: int) -> None:
    """In the forked child: become ``python -m MODULE ARGV`` in CWD with ENV, then exit. With
    ``fifos``, its output goes to those named pipes (the test reads them) instead."""
    import runpy
    import threading

    code = 0
    try:
        if "fifos" in request:
            out_fd = os.open(request["fifos"][0], os.O_WRONLY)
            err_fd = os.open(request["fifos"][1], os.O_WRONLY)
        os.chdir(request["cwd"])
        os.environ.clear()
        os.environ.update(request["env"])
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.dup2(out_fd, 1)
        os.dup2(err_fd, 2)
        sys.stdin = io.TextIOWrapper(io.FileIO(0, "r", closefd=False))
        sys.stdout = io.TextIOWrapper(io.FileIO(1, "w", closefd=False), write_through=True)
        sys.stderr = io.TextIOWrapper(io.FileIO(2, "w", closefd=False), write_through=True)
        sys.argv = [request["module"], *request["argv"]]
        # As under ``python -m``, the module runs as __main__ without having been imported first
        # (a preloaded one would make runpy warn on stderr).
        sys.modules.pop(request["module"], None)
        runpy.run_module(request["module"], run_name="__main__", alter_sys=True)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        if exc.code is not None and not isinstance(exc.code, int):
            print(exc.code, file=sys.stderr)
    except BaseException:  # as the interpreter would: the traceback, exit 1
        import traceback

        traceback.print_exc()
        code = 1
    finally:
        try:
            threading._shutdown()  # type: ignore[attr-defined]  # join non-daemon threads, as at exit
            atexit._run_exitfuncs()
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)


def _serve() -> None:
    import importlib

    for name in PRELOAD:
        importlib.import_module(name)
    from railstop.model.run import warm_up

    warm_up()
    replies = sys.stdout
    print("ready", file=replies, flush=True)
    spawned: dict[int, int | None] = {}  # pid -> exit code (None: running)
    for line in sys.stdin:
        request = json.loads(line)
        if "status" in request:
            pid = int(request["status"])
            if spawned.get(pid) is None:
                done, status = os.waitpid(pid, os.WNOHANG)
                if done:
                    spawned[pid] = os.waitstatus_to_exitcode(status)
            print(json.dumps({"rc": spawned.get(pid)}), file=replies, flush=True)
            continue
        if "spawn" in request:
            pid = os.fork()
            if pid == 0:
                _child(request, 1, 2)
            spawned[pid] = None
            print(json.dumps({"pid": pid}), file=replies, flush=True)
            continue
        with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
            pid = os.fork()
            if pid == 0:
                _child(request, out.fileno(), err.fileno())
            deadline = time.monotonic() + float(request["timeout"])
            rc: int | None = None
            while True:
                done, status = os.waitpid(pid, os.WNOHANG)
                if done:
                    rc = os.waitstatus_to_exitcode(status)
                    break
                if time.monotonic() > deadline:
                    os.kill(pid, 9)
                    os.waitpid(pid, 0)
                    break
                time.sleep(0.002)
            out.seek(0)
            err.seek(0)
            reply = {
                "rc": rc,
                "stdout": out.read().decode(errors="replace"),
                "stderr": err.read().decode(errors="replace"),
            }
        print(json.dumps(reply), file=replies, flush=True)


if __name__ == "__main__":
    _serve()
