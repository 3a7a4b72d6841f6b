"""The fixed-block interlocking: track-circuit occupancy in, signal aspects out (a pure unit).

The line before CBTC (**[interpretation]**: the source documents describe
CBTC and the station stop; the line simulation needs a conventional
baseline, and the CBTC issue replaces it). Each block is a run of track
circuits with a signal at its entry (``railstop.config.layout``). A signal
shows proceed when the ``blocks_ahead`` blocks from its own (1: its own) are
clear, and the circuits within ``overlap_m`` beyond the last of them too; any other
state, including a circuit whose state the unit has not been told, is a
stop aspect (DESIGN rule 10: unknown is occupied). The unit starts with an
empty line only when told so (``clear_at_start``), as a line simulation
does; a live unit waits for its first report of every circuit.
"""

from __future__ import annotations

from railstop.config.schema import Line
from railstop.errors import InterlockError
from railstop.messages import BROADCAST, CircuitOccupancy, Message, Output, SignalAspects


class FixedBlockInterlocking:
    accepts: tuple[type, ...] = (CircuitOccupancy,)

    def __init__(self, line: Line, *, name: str = "interlocking", clear_at_start: bool = False) -> None:
        if line.signalling is None:
            raise InterlockError(f"line {line.line.name!r} has no [signalling]: no blocks to interlock")
        self.name = name
        sig = line.signalling
        circuits = {c.id: c for c in line.track.circuits}
        self.block_circuits: list[tuple[int, ...]] = [tuple(b.circuits) for b in sig.blocks]
        self.signal_names: list[str] = [b.signal for b in sig.blocks]
        #: The signals' chainages: each stands at its block's start.
        self.signal_m: list[float] = [circuits[b.circuits[0]].start_m for b in sig.blocks]
        ordered = [c for b in sig.blocks for c in b.circuits]
        # For each signal: the circuits that must be clear for proceed (its blocks ahead, and
        # those reaching into the overlap beyond the last of them).
        self._needs: list[tuple[int, ...]] = []
        for k in range(len(sig.blocks)):
            last = min(k + sig.blocks_ahead, len(sig.blocks)) - 1
            need = [c for b in self.block_circuits[k : last + 1] for c in b]
            end = circuits[need[-1]].end_m
            after = ordered.index(need[-1]) + 1
            for cid in ordered[after:]:
                if circuits[cid].start_m >= end + sig.overlap_m:
                    break
                need.append(cid)
            self._needs.append(tuple(need))
        self._occupied: dict[int, bool] = {c: False for c in circuits} if clear_at_start else {}
        self._aspects = self._compute()

    def _compute(self) -> tuple[bool, ...]:
        # An unreported circuit counts as occupied (fail safe).
        return tuple(all(self._occupied.get(c) is False for c in need) for need in self._needs)

    @property
    def aspects(self) -> tuple[bool, ...]:
        return self._aspects

    def handle(self, message: Message, now_s: float) -> list[Output]:
        if not isinstance(message, CircuitOccupancy):
            what = type(message).__name__
            raise InterlockError(f"the interlocking takes track-circuit reports, not {what}")
        if message.circuit_id not in {c for b in self.block_circuits for c in b}:
            raise InterlockError(f"a report of track circuit {message.circuit_id}, which is in no block")
        self._occupied[message.circuit_id] = message.occupied
        aspects = self._compute()
        if aspects == self._aspects:
            return []
        self._aspects = aspects
        return [Output(to=BROADCAST, message=SignalAspects(proceed=aspects))]

    def next_deadline_s(self) -> float | None:
        return None

    def on_timer(self, now_s: float) -> list[Output]:
        return []
