"""Role-neutral messages between units (DESIGN rule 3): frozen dataclasses, nothing else.

Units import messages, never each other. A unit returns its outputs as
``Output`` pairs: the name of the unit it is for (or ``BROADCAST``) and the
message; the driver (a scheduler on simulated time, or a live runner) delivers
them, through the link model where a link is between the two.
"""

from __future__ import annotations

from dataclasses import dataclass

BROADCAST = "*"


@dataclass(frozen=True, slots=True, kw_only=True)
class CircuitOccupancy:
    """A wayside track-circuit device reports a circuit's state (SPEC §2: occupied / clear)."""

    circuit_id: int
    occupied: bool


@dataclass(frozen=True, slots=True, kw_only=True)
class SignalAspects:
    """The interlocking's signal aspects, every signal in running order: True = proceed."""

    proceed: tuple[bool, ...]


#: Every message a unit takes or sends.
Message = CircuitOccupancy | SignalAspects


@dataclass(frozen=True, slots=True, kw_only=True)
class Output:
    """A message for the unit named ``to`` (``BROADCAST``: every unit that takes its type)."""

    to: str
    message: Message
