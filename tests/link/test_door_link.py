"""The door link of SPEC §5: door-command up, psd-status down, through codec, safety layer and medium."""

from __future__ import annotations

import math

import pytest

from railstop.config.media import ChannelParams
from railstop.link.channel import LinkError, media_preset
from railstop.link.codec import DoorCommand, PsdStatus
from railstop.link.door_link import PLATFORM_ID, DoorLink

CMD = DoorCommand(
    train_id=7,
    doa_l=False,
    doa_r=True,
    dmc_l=True,
    dmc_r=False,
    doc=True,
    dcc=False,
    psc=True,
    automatic=True,
    doors_locked=0xFFFFFF,
)
STATUS = PsdStatus(
    train_id=7,
    psc=True,
    psd_closed_locked=False,
    start_enable=False,
    manual=False,
    fault=False,
    psd_open=0b101,
)


def link(params: ChannelParams | None = None, seed: int = 1, **kw: object) -> DoorLink:
    return DoorLink(
        params=params or media_preset("transponder"),
        seed=seed,
        train_id=7,
        **kw,  # type: ignore[arg-type]
    )


def drain(lk: DoorLink, until_s: float) -> list[tuple[str, object, float]]:
    out = []
    while (t := lk.next_arrival_s()) is not None and t <= until_s:
        out += [(r.to, r.telegram, r.at_s) for r in lk.deliver(t)]
    return out


@pytest.mark.parametrize("category", [1, 2, 3])
def test_both_ways_arrive_as_sent_after_the_medium_delay(category: int) -> None:
    lk = link(category=category)
    lk.send_command(CMD, 1.0)
    lk.send_status(STATUS, 1.0)
    got = drain(lk, 2.0)
    assert sorted((to, type(m).__name__) for to, m, _ in got) == [
        ("platform", "DoorCommand"),
        ("train", "PsdStatus"),
    ]
    assert dict((to, m) for to, m, _ in got) == {"platform": CMD, "train": STATUS}
    p = media_preset("transponder")
    for _, _, at in got:
        # One poll slot at most, the airtime, the latency (a few sd of jitter).
        assert 1.0 < at < 1.0 + p.cycle_s + 0.01 + p.latency_s + 5 * p.jitter_s
    c = lk.counts
    assert (c.commands_sent, c.commands_delivered, c.status_sent, c.status_delivered) == (1, 1, 1, 1)
    assert c.lost == 0 and c.rejected == {}


def test_an_outage_loses_every_frame_sent_inside_it_both_ways() -> None:
    lk = link(outage=(1.0, 2.0))
    for t in (0.5, 1.0, 1.5, 2.0):
        lk.send_command(CMD, t)
        lk.send_status(STATUS, t)
    got = drain(lk, 10.0)
    assert len(got) == 4  # the frames of 0.5 s and 2.0 s, both ways
    assert lk.counts.lost == 4


def test_corrupted_frames_are_refused_by_reason_and_counted() -> None:
    noisy = media_preset("transponder").replace(bit_error_rate=5e-3)
    lk = link(noisy, seed=3)
    n = 200
    for k in range(n):
        lk.send_command(CMD, 0.1 * k)
    got = drain(lk, 100.0)
    c = lk.counts
    assert all(m == CMD for _, m, _ in got)  # a damaged frame is never delivered
    assert c.rejected.get("corrupt", 0) > 50
    assert c.commands_delivered + sum(c.rejected.values()) + c.lost == n == c.commands_sent


def test_a_keyed_link_refuses_frames_of_another_train() -> None:
    """Category 3: a frame wrapped for train 8 is refused by train 7's platform end."""
    mine, other = (
        link(category=3),
        DoorLink(params=media_preset("transponder"), seed=1, train_id=8, category=3),
    )
    frame = other.train_end.frame(CMD, PLATFORM_ID, 1.0)
    assert frame is not None
    assert mine.platform_end.receive(frame, 1.0) is None
    assert mine.platform_end.rejected == {"unknown_peer": 1}  # refused before any key is tried
    # Train 8's own platform end takes it.
    got = other.platform_end.receive(frame, 1.0)
    assert got is not None and got[1] == CMD


@pytest.mark.parametrize(
    ("kw", "needle"),
    [
        ({"outage": (2.0, 1.0)}, "outage"),
        ({"outage": (math.nan, 1.0)}, "outage"),
        ({"train_id": 0xF000}, "train_id"),
    ],
)
def test_bad_settings_raise_naming_the_field(kw: dict[str, object], needle: str) -> None:
    args: dict[str, object] = {
        "params": media_preset("transponder"),
        "seed": 1,
        "train_id": 7,
    }
    args.update(kw)
    with pytest.raises(LinkError, match=needle):
        DoorLink(**args)  # type: ignore[arg-type]
