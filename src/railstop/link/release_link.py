"""The operator's commands, authenticated: the manual release of a protection zone (SPEC §4 step 5)
and the WCC's switch of a station's WPCS to manual (SPEC §5).

A released zone lets trains into track where a lost train may stand, so the
release travels only as a ``zone-release`` telegram in an EN 50159
**category 3** safety frame with the operator console's own key (a keyed
MAC, a sequence number, a timestamp): the :class:`ReleaseGate` in front of
the zone controller delivers a :class:`~railstop.messages.ManualRelease`
only for a frame that passes; a frame with a wrong key, replayed, stale or
damaged is refused and counted by its reason (DESIGN rule 10: nothing is
released on a doubtful command). The WCC's ``wcc-command`` travels the same
way to the stations' WPCS input (:class:`WccGate`): a doubtful one changes
nothing. Every command names the operator who sent it (the telegram's
``operator_id``, the id of the control room's login); a command that names
none (id 0) is refused, and the receiving end counts the accepted ones per
operator (``released_by``, ``commanded_by``).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

from railstop.errors import TelegramError
from railstop.link.codec import Telegram, WccCommand, ZoneRelease, decode, encode
from railstop.link.safety import Delivered, SafeReceiver, SafeSender, link_key
from railstop.messages import ManualRelease

__all__ = ["OPERATOR_ADDRESS", "OperatorConsole", "ReleaseGate", "WccGate", "release_key", "wcc_key"]

OPERATOR_ADDRESS = 0x0400  # the control room's operator console
ZC_RELEASE_ADDRESS = 0x0301  # the zone controller's release input
WCC_ADDRESS = 0x0302  # the stations' WPCS input from the WCC
# Demonstration master key of the release link (its own, not the radio's). A deployment loads it
# from its key management.
_DEMO_MASTER = hashlib.sha256(b"railstop demonstration zone release master key").digest()


def release_key(master: bytes = _DEMO_MASTER) -> bytes:
    """The key of the operator -> zone controller direction."""
    return link_key(master, OPERATOR_ADDRESS, ZC_RELEASE_ADDRESS)


def wcc_key(master: bytes = _DEMO_MASTER) -> bytes:
    """The key of the operator -> stations (WCC) direction."""
    return link_key(master, OPERATOR_ADDRESS, WCC_ADDRESS)


@dataclass(slots=True)
class OperatorConsole:
    """The sending end: ``release(train, now_s)`` (to the zone controller) or ``wcc(...)`` (to the
    stations, with ``to=WCC_ADDRESS`` and its key) gives the frame to send."""

    operator_id: int = 1
    key: bytes = field(default_factory=release_key)
    to: int = ZC_RELEASE_ADDRESS
    sender: SafeSender = field(init=False)

    def __post_init__(self) -> None:
        self.sender = SafeSender(OPERATOR_ADDRESS, self.to, key=self.key, category=3)

    def release(self, train_id: int, now_s: float, *, operator_id: int | None = None) -> bytes:
        """``operator_id``: the operator sending it (None: the console's own)."""
        who = self.operator_id if operator_id is None else operator_id
        return self.sender.wrap(encode(ZoneRelease(train_id=train_id, operator_id=who)), now_s)

    def wcc(
        self,
        station: int,
        *,
        manual: bool,
        panel_open: bool,
        panel_close: bool,
        now_s: float,
        operator_id: int | None = None,
    ) -> bytes:
        tele = WccCommand(
            station=station,
            manual=manual,
            panel_open=panel_open,
            panel_close=panel_close,
            operator_id=self.operator_id if operator_id is None else operator_id,
        )
        return self.sender.wrap(encode(tele), now_s)


@dataclass(slots=True)
class _Gate:
    """A receiving end of the operator's link: the telegram of a frame that passes the safety layer
    and the codec and is of the expected type, or None (refused, counted in ``rejected``)."""

    key: bytes
    own: int
    max_age_s: float = 5.0
    # When this end's process started (on the link's clock): commands sent before it are refused
    # (``old_session``), so one its previous incarnation took is not taken again when replayed
    # (EN 50159 repetition across restarts, ``link.safety``). None: no floor (the simulations).
    not_before_s: float | None = None
    receiver: SafeReceiver = field(init=False)
    rejected: dict[str, int] = field(default_factory=dict)
    accepted: int = 0
    by_operator: dict[int, int] = field(default_factory=dict)  # accepted commands per operator id

    def __post_init__(self) -> None:
        self.receiver = SafeReceiver(
            self.own,
            OPERATOR_ADDRESS,
            key=self.key,
            category=3,
            max_age_s=self.max_age_s,
            timeout_s=1e9,  # operator commands are rare: no supervision of their cycle
            not_before_s=self.not_before_s,
        )

    def take(self, frame: bytes, now_s: float, expect: type[Telegram]) -> Telegram | None:
        verdict = self.receiver.accept(frame, now_s)
        if not isinstance(verdict, Delivered):
            self._reject(verdict.reason)
            return None
        try:
            tele = decode(verdict.payload)
        except TelegramError as exc:
            self._reject(f"codec-{exc.reason}")
            return None
        if not isinstance(tele, expect):
            self._reject("unexpected-type")
            return None
        # SPEC §4 step 5 / §5: a command is an operator's; one that names none is refused.
        operator = getattr(tele, "operator_id", 0)
        if operator == 0:
            self._reject("no-operator")
            return None
        self.accepted += 1
        self.by_operator[operator] = self.by_operator.get(operator, 0) + 1
        return tele

    def _reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1


class ReleaseGate(_Gate):
    """The zone controller's end: ``accept(frame, now_s)`` -> a ManualRelease, or None."""

    __slots__ = ()

    def __init__(
        self, key: bytes | None = None, max_age_s: float = 5.0, not_before_s: float | None = None
    ) -> None:
        super().__init__(
            key=release_key() if key is None else key,
            own=ZC_RELEASE_ADDRESS,
            max_age_s=max_age_s,
            not_before_s=not_before_s,
        )

    def accept(self, frame: bytes, now_s: float) -> ManualRelease | None:
        tele = self.take(frame, now_s, ZoneRelease)
        if not isinstance(tele, ZoneRelease):
            return None
        return ManualRelease(train_id=tele.train_id)

    @property
    def released_by(self) -> dict[int, int]:
        """Releases accepted per operator id (the zone controller's record of who released)."""
        return dict(self.by_operator)


class WccGate(_Gate):
    """The stations' end of the WCC link: ``accept(frame, now_s)`` -> a WccCommand, or None. A
    command that presses a panel button outside manual mode, or both at once, is refused
    (``inconsistent``): it changes nothing."""

    __slots__ = ()

    def __init__(
        self, key: bytes | None = None, max_age_s: float = 5.0, not_before_s: float | None = None
    ) -> None:
        super().__init__(
            key=wcc_key() if key is None else key,
            own=WCC_ADDRESS,
            max_age_s=max_age_s,
            not_before_s=not_before_s,
        )

    def accept(self, frame: bytes, now_s: float) -> WccCommand | None:
        tele = self.take(frame, now_s, WccCommand)
        if not isinstance(tele, WccCommand):
            return None
        if ((tele.panel_open or tele.panel_close) and not tele.manual) or (
            tele.panel_open and tele.panel_close
        ):
            self.accepted -= 1
            self.by_operator[tele.operator_id] -= 1
            self._reject("inconsistent")
            return None
        return tele

    @property
    def commanded_by(self) -> dict[int, int]:
        """Commands accepted per operator id."""
        return {k: v for k, v in self.by_operator.items() if v}
