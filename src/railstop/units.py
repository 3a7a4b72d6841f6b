"""The one unit contract (DESIGN rule 2).

Every box of the source documents' diagrams that decides something is a unit:
it is told the time, never reads a clock; it returns its outputs, never sends
them. A driver calls ``handle`` with each message for it, asks
``next_deadline_s`` when it next needs waking without one (a time-out, a
cycle), and calls ``on_timer`` then. The same unit runs on simulated time
(``railstop.clock``) and, later, on the wall clock.
"""

from __future__ import annotations

from typing import Protocol

from railstop.messages import Message, Output


class Unit(Protocol):
    name: str
    accepts: tuple[type, ...]  # the message types it takes (a broadcast reaches those units only)

    def handle(self, message: Message, now_s: float) -> list[Output]:
        """Take one message at ``now_s``; what to send because of it."""
        ...

    def next_deadline_s(self) -> float | None:
        """When the unit must be woken without a message (None: not before the next message)."""
        ...

    def on_timer(self, now_s: float) -> list[Output]:
        """The deadline came: what to send."""
        ...
