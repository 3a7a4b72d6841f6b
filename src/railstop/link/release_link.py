"""The operator's manual release of a protection zone (SPEC §4 step 5), authenticated.

A released zone lets trains into track where a lost train may stand, so the
release travels only as a ``zone-release`` telegram in an EN 50159
**category 3** safety frame with the operator console's own key (a keyed
MAC, a sequence number, a timestamp): the :class:`ReleaseGate` in front of
the zone controller delivers a :class:`~railstop.messages.ManualRelease`
only for a frame that passes; a frame with a wrong key, replayed, stale or
damaged is refused and counted by its reason (DESIGN rule 10: nothing is
released on a doubtful command).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

from railstop.errors import TelegramError
from railstop.link.codec import ZoneRelease, decode, encode
from railstop.link.safety import Delivered, SafeReceiver, SafeSender, link_key
from railstop.messages import ManualRelease

__all__ = ["OPERATOR_ADDRESS", "OperatorConsole", "ReleaseGate", "release_key"]

OPERATOR_ADDRESS = 0x0400  # the control room's operator console
ZC_RELEASE_ADDRESS = 0x0301  # the zone controller's release input
# Demonstration master key of the release link (its own, not the radio's). A deployment loads it
# from its key management.
_DEMO_MASTER = hashlib.sha256(b"railstop demonstration zone release master key").digest()


def release_key(master: bytes = _DEMO_MASTER) -> bytes:
    """The key of the operator -> zone controller direction."""
    return link_key(master, OPERATOR_ADDRESS, ZC_RELEASE_ADDRESS)


@dataclass(slots=True)
class OperatorConsole:
    """The sending end: ``release(train, now_s)`` gives the frame to send."""

    operator_id: int = 1
    key: bytes = field(default_factory=release_key)
    sender: SafeSender = field(init=False)

    def __post_init__(self) -> None:
        self.sender = SafeSender(OPERATOR_ADDRESS, ZC_RELEASE_ADDRESS, key=self.key, category=3)

    def release(self, train_id: int, now_s: float) -> bytes:
        return self.sender.wrap(encode(ZoneRelease(train_id=train_id, operator_id=self.operator_id)), now_s)


@dataclass(slots=True)
class ReleaseGate:
    """The zone controller's end: ``accept(frame, now_s)`` -> a ManualRelease, or None (refused,
    counted in ``rejected`` by reason)."""

    key: bytes = field(default_factory=release_key)
    max_age_s: float = 5.0
    receiver: SafeReceiver = field(init=False)
    rejected: dict[str, int] = field(default_factory=dict)
    accepted: int = 0

    def __post_init__(self) -> None:
        self.receiver = SafeReceiver(
            ZC_RELEASE_ADDRESS,
            OPERATOR_ADDRESS,
            key=self.key,
            category=3,
            max_age_s=self.max_age_s,
            timeout_s=1e9,  # releases are rare: no supervision of their cycle
        )

    def accept(self, frame: bytes, now_s: float) -> ManualRelease | None:
        verdict = self.receiver.accept(frame, now_s)
        if not isinstance(verdict, Delivered):
            self._reject(verdict.reason)
            return None
        try:
            tele = decode(verdict.payload)
        except TelegramError as exc:
            self._reject(f"codec-{exc.reason}")
            return None
        if not isinstance(tele, ZoneRelease):
            self._reject("unexpected-type")
            return None
        self.accepted += 1
        return ManualRelease(train_id=tele.train_id)

    def _reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
