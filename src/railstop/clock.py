"""One scheduler for simulated time (DESIGN rule 5): the plant's fixed step and a heap of deadlines.

The plant (true motion, sensors) advances by a fixed step; between steps the
units' own deadlines (cycles, time-outs) fire in time order, each at its own
time. Outputs are delivered at once, in order, to the unit they name (or, for
a broadcast, to every unit that accepts the message's type); a unit's answer
is delivered in turn. A link with latency and loss is a unit of its own
between two others (the channel), so this scheduler knows no transport. The
live mode will subclass it and wait on the wall clock instead of jumping.
"""

from __future__ import annotations

import heapq
from collections import deque
from collections.abc import Callable, Iterable

from railstop.errors import SimulationError
from railstop.messages import BROADCAST, Output
from railstop.units import Unit

#: A plant step: (now_s, step_s) -> outputs of the sensors (messages for the units).
PlantStep = Callable[[float, float], list[Output]]

#: More deliveries than this from one event means units answering each other for ever.
MAX_CASCADE = 10_000


class SimClock:
    def __init__(self, units: Iterable[Unit], *, step_s: float, start_s: float = 0.0) -> None:
        if not step_s > 0.0:
            raise SimulationError(f"the plant step must be positive (got {step_s})")
        self.step_s = step_s
        self.now_s = start_s
        self.units: dict[str, Unit] = {}
        for u in units:
            if u.name in self.units or u.name == BROADCAST:
                raise SimulationError(f"unit name {u.name!r} is taken")
            self.units[u.name] = u
        self._heap: list[tuple[float, int, str, float]] = []  # (when, order, unit, its deadline)
        self._seq = 0
        self.delivered = 0
        for name in self.units:
            self._arm(name)

    def _arm(self, name: str) -> None:
        deadline = self.units[name].next_deadline_s()
        if deadline is not None:
            self._seq += 1
            heapq.heappush(self._heap, (max(deadline, self.now_s), self._seq, name, deadline))

    def deliver(self, outputs: Iterable[Output]) -> None:
        """Deliver ``outputs`` and everything they cause, now."""
        queue = deque(outputs)
        count = 0
        while queue:
            out = queue.popleft()
            if out.to == BROADCAST:
                targets = [u for u in self.units.values() if isinstance(out.message, u.accepts)]
            else:
                unit = self.units.get(out.to)
                if unit is None:
                    raise SimulationError(f"a message for {out.to!r}, which is not a unit here")
                targets = [unit]
            for unit in targets:
                count += 1
                if count > MAX_CASCADE:
                    raise SimulationError(f"more than {MAX_CASCADE} deliveries at {self.now_s} s: a loop")
                queue.extend(unit.handle(out.message, self.now_s))
                self._arm(unit.name)
        self.delivered += count

    def _fire_until(self, t_s: float) -> None:
        while self._heap and self._heap[0][0] <= t_s + 1e-12:
            when, _, name, deadline = heapq.heappop(self._heap)
            unit = self.units[name]
            if unit.next_deadline_s() != deadline:
                continue  # a stale entry: the unit moved its deadline
            self.now_s = when
            outs = unit.on_timer(when)
            self._arm(name)
            self.deliver(outs)

    def run(self, until_s: float, plant: PlantStep) -> None:
        """Advance to ``until_s``: deadlines in time order, the plant every step."""
        while self.now_s + self.step_s <= until_s + 1e-9:
            t_next = self.now_s + self.step_s
            self._fire_until(t_next)
            self.now_s = t_next
            self.deliver(plant(self.now_s, self.step_s))
