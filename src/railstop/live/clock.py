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
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Iterable

from railstop.messages import Output
from railstop.sim.clock import PlantStep, SimClock
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
    """The simulated-time scheduler of ``railstop.sim.clock``, paced by a :class:`TimeBase`."""

    def __init__(self, units: Iterable[Unit], *, step_s: float, base: TimeBase) -> None:
        super().__init__(units, step_s=step_s, start_s=base.now_s())
        self.base = base
        self.late_steps = 0
        self.late_max_s = 0.0  # the latest a step started (simulated seconds after its time)
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
            if wait > 0.0:
                try:
                    await asyncio.wait_for(stop.wait(), timeout=wait)
                    break
                except TimeoutError:
                    pass
            else:
                self.late_max_s = max(self.late_max_s, -wait * self.base.scale)
                if -wait * self.base.scale > self.step_s:
                    self.late_steps += 1
            self._fire_until(t_next)
            self.now_s = t_next
            # What arrived on the sockets since the last step, at the time it is taken.
            self.deliver(poll(self.now_s))
            self.deliver(plant(self.now_s, self.step_s))
            self.steps += 1
