"""One direction of a simulated link with the codec and the EN 50159 safety layer at its ends.

``send(telegram, now_s)``: encode (a value the telegram cannot carry is refused and counted,
nothing is sent), wrap in a safety frame, and hand it to the medium, unless an outage (fault
data: every frame sent inside ``[start_s, end_s)`` is lost) swallows it. ``receive(now_s)``:
the frames the medium has delivered by then, checked by the safety layer and decoded; a frame
either refuses is dropped and counted by its reason, never delivered. The door link and the
CBTC radio are built of these (DESIGN rule 5: one link model, codec and safety at its ends).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from railstop.errors import TelegramError
from railstop.link.channel import SimChannel
from railstop.link.codec import Telegram, decode, encode
from railstop.link.safety import Delivered, SafeReceiver, SafeSender

__all__ = ["SafeChannel"]


@dataclass(slots=True)
class SafeChannel:
    sender: SafeSender
    channel: SimChannel
    receiver: SafeReceiver
    outages: tuple[tuple[float, float], ...] = ()
    sent: int = 0  # telegrams handed to send()
    outage_lost: int = 0
    rejected: dict[str, int] = field(default_factory=dict)  # by reason: encode-*, safety layer, codec-*

    def send(self, msg: Telegram, now_s: float) -> bool:
        """True when the frame went onto the medium (which may still lose it)."""
        self.sent += 1
        try:
            payload = encode(msg)
        except TelegramError as exc:
            # A value the telegram cannot carry: nothing is sent (the receiver sees a missed
            # telegram, which its supervision handles).
            self._reject(f"encode-{exc.reason}")
            return False
        frame = self.sender.wrap(payload, now_s)
        if any(a <= now_s < b for a, b in self.outages):
            self.outage_lost += 1  # fault injection: nothing gets through
            return False
        self.channel.send(frame, now_s)
        return True

    def receive(self, now_s: float) -> list[Telegram]:
        """The telegrams arrived by ``now_s`` that passed the safety layer and the codec, in order."""
        out: list[Telegram] = []
        for frame in self.channel.receive(now_s):
            verdict = self.receiver.accept(frame, now_s)
            if not isinstance(verdict, Delivered):
                self._reject(verdict.reason)
                continue
            try:
                out.append(decode(verdict.payload))
            except TelegramError as exc:
                self._reject(f"codec-{exc.reason}")  # a valid safety frame around a bad telegram
        return out

    def next_arrival_s(self) -> float | None:
        return self.channel.next_arrival_s()

    @property
    def lost(self) -> int:
        """Frames the medium or an outage lost."""
        return self.channel.stats.lost + self.outage_lost

    @property
    def delivered(self) -> int:
        """Frames the safety layer accepted."""
        return self.receiver.counts["delivered"]

    def _reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
