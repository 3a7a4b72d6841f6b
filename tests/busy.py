"""A loaded machine for the live tests: CPU-bound processes that run beside a test.

The live processes keep their periods on the wall clock; a test of them must hold on a machine
whose cores are taken by other work too. :func:`busy` starts ``n`` processes that spin on the
CPU (pure Python, no sleep, no I/O) for as long as the ``with`` block runs and kills them after
it; ``tests/conftest.py`` offers it as the ``busy`` fixture and, with ``pytest --busy N``, beside
every test of the session.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

#: The spinning loop: one core's worth of work until killed.
_SPIN = "while True:\n    pass\n"


@dataclass
class Busy:
    """The processes spinning beside a test; ``cpu_s()`` is their CPU time so far (the proof that
    they took the CPU)."""

    procs: list[subprocess.Popen[bytes]] = field(default_factory=list)

    def cpu_s(self) -> float:
        """The CPU seconds (user + system) the spinning processes have used, from ``/proc``."""
        tick = os.sysconf("SC_CLK_TCK")
        total = 0.0
        for p in self.procs:
            with contextlib.suppress(OSError, IndexError, ValueError):
                fields = open(f"/proc/{p.pid}/stat").read().rsplit(")", 1)[1].split()  # noqa: SIM115
                total += (int(fields[11]) + int(fields[12])) / tick  # utime, stime
        return total


@contextlib.contextmanager
def busy(n: int = 2) -> Iterator[Busy]:
    """``n`` CPU-bound processes running for the duration of the block."""
    b = Busy()
    try:
        for _ in range(n):
            b.procs.append(subprocess.Popen([sys.executable, "-c", _SPIN]))
        time.sleep(0.05)  # they are running before the test begins
        yield b
    finally:
        for p in b.procs:
            p.kill()
        for p in b.procs:
            p.wait(timeout=30)
