"""The wayside position-correction device of SPEC §2 as a pure unit: occupancy event -> telegram.

SPEC §2: the wayside device has its own GNSS receiver (for time only) and an
occupancy-computation module that turns the occupancy information of the
track-circuit device into (occupied track-circuit ID, occupancy instant in
GNSS time), sent to the train by radio (S20).

The unit is pure (DESIGN rule 2): the occupancy indications and the reading
of its GNSS clock at that instant come in as arguments, telegrams go out.
Per circuit it keeps CLEAR / OCCUPIED in a transition table; only the
CLEAR -> OCCUPIED transition makes a telegram (a repeated "occupied"
indication is not a new occupancy). It works over arrays: the state has one
row per run, and a call handles any number of indications of any runs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from railstop.errors import SimulationError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


class CircuitState(IntEnum):
    CLEAR = 0
    OCCUPIED = 1


class Indication(IntEnum):
    """What the track-circuit device reports for a circuit."""

    CLEAR = 0
    OCCUPIED = 1


# (state, indication) -> (next state, send a telegram). Every pair is allowed:
# the device's indications are facts about the track, not requests.
TRANSITIONS: dict[tuple[CircuitState, Indication], tuple[CircuitState, bool]] = {
    (CircuitState.CLEAR, Indication.OCCUPIED): (CircuitState.OCCUPIED, True),  # SPEC §2 S10 -> S20
    (CircuitState.CLEAR, Indication.CLEAR): (CircuitState.CLEAR, False),
    (CircuitState.OCCUPIED, Indication.OCCUPIED): (CircuitState.OCCUPIED, False),
    (CircuitState.OCCUPIED, Indication.CLEAR): (CircuitState.CLEAR, False),
}

# The table as arrays, indexed [state, indication].
_NEXT = np.array([[TRANSITIONS[(s, i)][0] for i in Indication] for s in CircuitState], dtype=np.int8)
_SEND = np.array([[TRANSITIONS[(s, i)][1] for i in Indication] for s in CircuitState], dtype=bool)


@dataclass(frozen=True, slots=True, kw_only=True)
class OccupancyTelegram:
    """SPEC §2 S20: the occupied track circuit and the occupancy instant in GNSS time."""

    circuit_id: int
    gnss_time_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class OccupancyTelegrams:
    """Telegrams of several runs at once (k rows)."""

    run: IntArray
    circuit_id: IntArray
    gnss_time_s: FloatArray
    source: IntArray | None = None  # row of the indication that made each telegram (handle's input)

    @property
    def size(self) -> int:
        return int(self.run.size)

    def telegram(self, k: int) -> OccupancyTelegram:
        return OccupancyTelegram(circuit_id=int(self.circuit_id[k]), gnss_time_s=float(self.gnss_time_s[k]))


class TimestampUnit:
    """SPEC §2 wayside position-correction device for the circuits of a line, n runs."""

    def __init__(self, circuit_ids: Sequence[int], n: int) -> None:
        ids = np.asarray(list(circuit_ids), dtype=np.int64)
        if ids.size == 0:
            raise SimulationError("track circuits: a time-stamping unit needs at least one circuit")
        if np.unique(ids).size != ids.size:
            raise SimulationError(f"track circuits: IDs must be unique, got {ids.tolist()}")
        self.circuit_ids = ids
        self.state = np.zeros((n, ids.size), dtype=np.int8)  # CircuitState per run and circuit
        self.sent = np.zeros(n, dtype=np.int64)

    def occupy_initial(self, run: IntArray, circuit_index: IntArray) -> None:
        """Circuits already occupied when the simulation starts (no telegram)."""
        self.state[run, circuit_index] = CircuitState.OCCUPIED

    def handle(
        self,
        *,
        run: IntArray,
        circuit_index: IntArray,
        indication: Indication | IntArray,
        clock_time_s: FloatArray,
    ) -> OccupancyTelegrams:
        """Indications of the track-circuit devices; ``clock_time_s`` is this unit's GNSS clock then.

        Returns the telegrams to send (SPEC §2 S20), one per CLEAR -> OCCUPIED transition.
        """
        run = np.asarray(run, dtype=np.int64)
        idx = np.asarray(circuit_index, dtype=np.int64)
        if np.any((idx < 0) | (idx >= self.circuit_ids.size)):
            raise SimulationError(f"track circuits: no circuit index {idx.tolist()} on this line")
        ind = np.broadcast_to(np.asarray(indication, dtype=np.int64), idx.shape)
        times = np.broadcast_to(np.asarray(clock_time_s, dtype=np.float64), idx.shape)
        send = np.zeros(idx.size, dtype=bool)
        # Sequential over the k indications: two of the same circuit in one call must see each other.
        for k in range(idx.size):
            s = self.state[run[k], idx[k]]
            send[k] = _SEND[s, ind[k]]
            self.state[run[k], idx[k]] = _NEXT[s, ind[k]]
        np.add.at(self.sent, run[send], 1)
        return OccupancyTelegrams(
            run=run[send],
            circuit_id=self.circuit_ids[idx[send]],
            gnss_time_s=times[send].copy(),
            source=np.flatnonzero(send),
        )
