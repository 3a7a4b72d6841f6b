"""The scheduler on the wall clock (DESIGN rule 5): ``SimClock`` that waits instead of jumping.

Live processes share one time base: ``epoch`` (seconds since 1970 at the
live run's start, passed to every process) and ``scale`` (simulated seconds
per wall second: 1 real time, 10 ten times faster). Simulated time is
``(time.time() - epoch) * scale``; every process reads it the same way, so the
safety layer's timestamps agree between processes (the assumption of
``link.safety``: synchronised clocks, here the host's).

Each plant step the clock waits until the wall clock reaches the step's time,
takes what arrived on the sockets (``poll``), fires the units' deadlines in
time order and runs the plant. A step that starts more than one step late is
counted (``late_steps``): the process could not keep up.

A process that fell behind (its CPU taken by others, a stall of the host)
catches up step by step (the plant's motion and the deadlines keep their
order), and on a loaded machine it must not lose what reached it meanwhile:
each late step still yields to the event loop, so that the frames waiting in
the sockets are read (and a task serving another socket runs) before the
deadlines of the next step fire; and ``poll`` is given the wall clock's time,
not the late step's, so that the safety layer judges a frame's age at the
time it is really taken (a frame is never refused as "from the future"
because its receiver is behind). Without both, a process whose steps run
late would count reports, commands or drives as missed that it had received.
"""

from __future__ import annotations

import asyncio
import gc
import time
from collections.abc import Callable, Iterable
from typing import Any

from railstop.clock import PlantStep, SimClock
from railstop.messages import Output
from railstop.units import Unit


class TimeBase:
    """Simulated seconds since the live run's epoch, ``scale`` times the wall clock."""

    def __init__(self, epoch: float, scale: float) -> None:
        if not scale > 0.0:
            raise ValueError(f"scale must be positive (got {scale})")
        self.epoch, self.scale = epoch, scale
        # The only wall-clock read: the monotonic clock placed on the shared epoch.
        self._offset = time.time() - time.monotonic() - epoch

    def now_s(self) -> float:
        return (time.monotonic() + self._offset) * self.scale

    def wall_until(self, sim_s: float) -> float:
        """Wall seconds from now until simulated time ``sim_s`` (<= 0: already there)."""
        return (sim_s - self.now_s()) / self.scale


class WallClock(SimClock):
    """The simulated-time scheduler of ``railstop.clock``, paced by a :class:`TimeBase`."""

    def __init__(self, units: Iterable[Unit], *, step_s: float, base: TimeBase) -> None:
        super().__init__(units, step_s=step_s, start_s=base.now_s())
        self.base = base
        self.late_steps = 0
        self.late_max_s = 0.0  # the latest a step started (simulated seconds after its time)
        self.late_at: list[float] = []  # when the first LATE_KEPT late steps were due (Unix time)
        self.steps = 0

    async def run_live(
        self,
        plant: PlantStep,
        poll: Callable[[float], list[Output]],
        stop: asyncio.Event,
        until_s: float | None = None,
    ) -> None:
        """Run until ``stop`` is set (or simulated ``until_s``): wait, poll, deadlines, plant."""
        while not stop.is_set() and (until_s is None or self.now_s < until_s):
            t_next = self.now_s + self.step_s
            wait = self.base.wall_until(t_next)
            late = wait <= 0.0
            if not late:
                try:
                    await asyncio.wait_for(stop.wait(), timeout=wait)
                    break
                except TimeoutError:
                    pass
            else:
                self.late_max_s = max(self.late_max_s, -wait * self.base.scale)
                if -wait * self.base.scale > self.step_s:
                    self.late_steps += 1
                    if len(self.late_at) < LATE_KEPT:
                        self.late_at.append(self.base.epoch + t_next / self.base.scale)
                await asyncio.sleep(0)  # late: the sockets are read all the same (see the notes)
            self._fire_until(t_next)
            self.now_s = t_next
            # What arrived on the sockets since the last step, at the time it is taken (late: the
            # wall clock's, the safety layer's "now"; the units get it at the step's time).
            self.deliver(poll(max(self.now_s, self.base.now_s()) if late else self.now_s))
            self.deliver(plant(self.now_s, self.step_s))
            self.steps += 1

    def timing(self) -> dict[str, Any]:
        """The clock's figures for a process's counts: steps, the steps that started more than
        one step late, the latest start, and when the first of the late ones were due."""
        return {
            "steps": self.steps,
            "late_steps": self.late_steps,
            "late_max_ms": round(self.late_max_s * 1000.0, 1),
            "late_at_unix": [round(t, 3) for t in self.late_at],
        }


LATE_KEPT = 100  # late steps whose times a clock keeps


class GcWatch:
    """The garbage collector's pauses in this process (``gc.callbacks``): the collections that
    took longer than ``over_s``, the longest, and when the first of them began (Unix time), to
    set beside a clock's late steps."""

    def __init__(self, over_s: float = 0.005) -> None:
        self.over_s = over_s
        self.collections = 0
        self.long = 0
        self.max_s = 0.0
        self.long_at: list[tuple[float, float]] = []  # (Unix time, seconds) of the first long ones
        self._began = 0.0
        self._began_unix = 0.0

    def __enter__(self) -> GcWatch:
        gc.callbacks.append(self._on_gc)
        return self

    def __exit__(self, *exc: object) -> None:
        gc.callbacks.remove(self._on_gc)

    def _on_gc(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._began, self._began_unix = time.perf_counter(), time.time()
            return
        took = time.perf_counter() - self._began
        self.collections += 1
        self.max_s = max(self.max_s, took)
        if took > self.over_s:
            self.long += 1
            if len(self.long_at) < LATE_KEPT:
                self.long_at.append((round(self._began_unix, 3), round(took * 1000.0, 1)))

    def counts(self) -> dict[str, Any]:
        return {
            "collections": self.collections,
            f"over_{self.over_s * 1000.0:g}_ms": self.long,
            "max_ms": round(self.max_s * 1000.0, 1),
            "long_at_unix_ms": self.long_at,
        }
