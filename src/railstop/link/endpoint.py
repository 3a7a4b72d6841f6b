"""One party's end of a link: telegrams to safety frames and back (DESIGN rule 5: one endpoint).

An :class:`Endpoint` turns a telegram handed to it for a peer into a frame:
the codec (``link.codec``: type, fixed-point payload, CRC-16), then the EN
50159 safety layer (``link.safety.SafePeers``: ids, sequence number,
timestamp; a CRC-32 in categories 1 and 2, a MAC with a key per direction in
category 3). A frame received becomes the telegram again when the safety
layer and the codec accept it and it is one of the types this end takes.
What either refuses is counted by reason (``rejected``), never raised
(DESIGN rule 9): ``encode-<reason>`` for a value a telegram cannot carry
(nothing is sent; the peer's supervision sees a missed telegram),
``codec-<reason>`` for a valid safety frame around a bad telegram,
``unexpected-type`` for a telegram this end does not take, and the safety
layer's reasons.

Pure: the caller carries the frames, over a simulated medium
(``link.channel.SimChannel``) or UDP, and owns the clock. The CBTC radio
(``link.cbtc_radio``), the simulated door link (``link.door_link``) and the
live door link (``live.doors``) are built on it.
"""

from __future__ import annotations

from collections.abc import Callable

from railstop.link.codec import Telegram, TelegramError, decode, encode
from railstop.link.safety import MAX_PEERS, SafePeers

__all__ = ["Endpoint"]


class Endpoint:
    """One party's end of a link with its ``peers`` (see the module docstring).

    ``expects``: the telegram types this end takes (empty: any). ``started_s``: when this end
    (its process) started; frames sent before it are refused (``old_session``). ``simulated``: a
    simulation's end, which may use a built-in demonstration key (``SafePeers``)."""

    def __init__(
        self,
        own_id: int,
        *,
        peers: Callable[[int], bool],
        max_age_s: float,
        category: int = 3,
        master_key: bytes | None = None,
        expects: tuple[type[Telegram], ...] = (),
        started_s: float | None = None,
        simulated: bool = False,
        max_peers: int = MAX_PEERS,
    ) -> None:
        self.own_id = own_id
        self.expects = expects
        self.links = SafePeers(
            own_id,
            master_key,
            max_age_s=max_age_s,
            peers=peers,
            max_peers=max_peers,
            started_s=started_s,
            simulated=simulated,
            category=category,
        )

    def frame(self, telegram: Telegram, peer: int, now_s: float) -> bytes | None:
        """The frame of ``telegram`` for ``peer`` sent at ``now_s``, or None (counted) when a value
        of it cannot be carried."""
        try:
            payload = encode(telegram)
        except TelegramError as exc:
            self.links.reject(f"encode-{exc.reason}")
            return None
        return self.links.wrap(payload, peer, now_s)

    def receive(self, frame: bytes, now_s: float) -> tuple[int, Telegram] | None:
        """(peer, telegram) of a frame received at ``now_s``, or None with the reason counted."""
        got = self.links.accept(frame, now_s)
        if got is None:
            return None
        peer, delivered = got
        try:
            telegram = decode(delivered.payload)
        except TelegramError as exc:
            self.links.reject(f"codec-{exc.reason}")
            return None
        if self.expects and not isinstance(telegram, self.expects):
            self.links.reject("unexpected-type")
            return None
        return peer, telegram

    @property
    def sent(self) -> int:
        """Frames made (:meth:`frame` calls that gave one)."""
        return self.links.sent

    @property
    def delivered(self) -> int:
        """Frames the safety layer accepted."""
        return self.links.delivered

    @property
    def rejected(self) -> dict[str, int]:
        """Refusals by reason (safety layer, codec, encoding, type)."""
        return self.links.rejected
