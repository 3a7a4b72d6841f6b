"""Simulated train↔platform media (SPEC §5): railstop.link.channel.

Statistical checks compare a simulated rate with its analytic value, with a
tolerance of 5 standard deviations of the estimate for the sample size (for
the Gilbert–Elliott chain, the variance includes the chain's autocorrelation).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from railstop.config.media import ChannelParams, load_media
from railstop.errors import ConfigError, RailstopError
from railstop.link.channel import (
    LinkError,
    LinkStreams,
    SimChannel,
    airtime_s,
    corruption_probability,
    delivery_delay_s,
    mean_delivery_delay_s,
    media_preset,
    propagation_delay_s,
    stationary_loss_probability,
)
from railstop.streams import Stream, py_key_normal, py_key_uniform

Z = 5.0  # tolerance in standard deviations


def keys(seed: int) -> LinkStreams:
    """A test link's counter-based streams."""
    return LinkStreams.for_link(seed, Stream.DOOR_LINK, 99)


def frame(i: int, n_bytes: int = 12) -> bytes:
    """Frame i: its index (4 bytes) then zero padding, so a received copy says which frame it is."""
    return i.to_bytes(4, "big") + bytes(n_bytes - 4)


def index(f: bytes) -> int:
    return int.from_bytes(f[:4], "big")


def drain(ch: SimChannel) -> list[tuple[float, bytes]]:
    """Every frame still in flight, with its arrival time, by stepping from arrival to arrival."""
    out: list[tuple[float, bytes]] = []
    while (t := ch.next_arrival_s()) is not None:
        out.extend((t, f) for f in ch.receive(t))
    return out


def send_all(params: ChannelParams, seed: int, n: int, spacing_s: float = 0.01, n_bytes: int = 12):
    ch = SimChannel(params, keys(seed))
    for i in range(n):
        ch.send(frame(i, n_bytes), i * spacing_s)
    return ch, drain(ch)


def within(observed: float, expected: float, sd: float) -> None:
    assert abs(observed - expected) <= Z * sd, f"{observed} vs {expected} ± {Z} x {sd}"


def markov_mean_sd(pi: float, lam: float, n: int) -> float:
    """sd of the mean of a stationary two-state chain's indicator: Var ≈ π(1−π)/n · (1+λ)/(1−λ)."""
    return math.sqrt(pi * (1.0 - pi) / n * (1.0 + lam) / (1.0 - lam))


BUSY = ChannelParams(
    bit_rate_bps=9600.0,
    cycle_s=0.02,
    latency_s=0.02,
    jitter_s=0.01,
    loss_probability=0.05,
    burst_enter_probability=0.02,
    burst_exit_probability=0.2,
    burst_loss_probability=0.7,
    duplicate_probability=0.05,
    reorder_probability=0.05,
    reorder_delay_s=0.1,
    bit_error_rate=1e-3,
    overhead_bits=24,
)


# --------------------------------------------------------------------------
# Determinism


def test_same_seed_gives_same_frames_times_and_stats() -> None:
    ch1, out1 = send_all(BUSY, seed=7, n=2000, spacing_s=0.03)
    ch2, out2 = send_all(BUSY, seed=7, n=2000, spacing_s=0.03)
    assert out1 == out2
    assert ch1.stats == ch2.stats
    # Every effect was exercised, so the equality above covers them all.
    s = ch1.stats
    assert min(s.lost, s.duplicated, s.reordered, s.corrupted, s.sent_in_burst) > 0
    _, out3 = send_all(BUSY, seed=8, n=2000, spacing_s=0.03)
    assert out3 != out1


# --------------------------------------------------------------------------
# Airtime and delays


def test_airtime_by_hand() -> None:
    p = ChannelParams(bit_rate_bps=2400.0, overhead_bits=40)
    # 10 bytes: (80 + 40) bits / 2400 bit/s = 0.05 s
    assert airtime_s(p, 10) == pytest.approx(0.05, rel=1e-12)
    # 0, 1 and 64 bytes: 40, 48 and 552 bits
    got = airtime_s(p, np.array([0, 1, 64]))
    np.testing.assert_allclose(got, [40 / 2400, 48 / 2400, 552 / 2400], rtol=1e-12)
    # transponder rate of SPEC §5: 10 bytes + 32 overhead bits at 64 kbit/s = 112 / 64000 s
    q = ChannelParams(bit_rate_bps=64000.0, overhead_bits=32)
    assert airtime_s(q, 10) == pytest.approx(112 / 64000, rel=1e-12)


def test_isolated_frame_arrives_after_airtime_plus_latency() -> None:
    p = ChannelParams(bit_rate_bps=2400.0, overhead_bits=40, latency_s=0.01)
    ch = SimChannel(p, keys(0))
    ch.send(bytes(10), 1.0)
    assert ch.next_arrival_s() == pytest.approx(1.0 + 0.05 + 0.01, abs=1e-12)
    assert ch.receive(1.0599) == []
    assert ch.receive(1.0601) == [bytes(10)]


def test_latency_is_never_negative() -> None:
    p = ChannelParams(bit_rate_bps=1e6, latency_s=0.01, jitter_s=0.05)
    z = np.linspace(-10.0, 10.0, 101)
    d = np.asarray(propagation_delay_s(p, z))
    assert np.all(d >= 0.0)
    assert d[0] == 0.0 and d[-1] == pytest.approx(0.01 + 0.5)


def test_one_model_vectorised_delay_equals_simchannel() -> None:
    """delivery_delay_s on the SimChannel's own draws gives exactly its arrival times."""
    cycle = 0.25
    p = ChannelParams(
        bit_rate_bps=2400.0,
        cycle_s=cycle,
        latency_s=0.05,
        jitter_s=0.03,
        loss_probability=0.1,
        reorder_probability=0.3,
        reorder_delay_s=0.07,
        overhead_bits=16,
    )
    seed, n = 11, 400
    layout = np.random.default_rng(99)
    send_s = 2.0 * np.arange(n) + layout.random(n)  # isolated frames: >= 1 s apart
    sizes = layout.integers(1, 40, n)
    ch = SimChannel(p, keys(seed))
    for i in range(n):
        ch.send(frame(i, int(sizes[i]) + 4), float(send_s[i]))
    arrived = {index(f): t for t, f in drain(ch)}

    # Replay the documented draws: frame i's loss, reorder and jitter at counter i of its streams.
    k = keys(seed)
    u5 = np.zeros((n, 5))
    z = np.empty(n)
    for i in range(n):
        u5[i, 2] = py_key_uniform(k.loss, i)
        u5[i, 4] = py_key_uniform(k.faults, 4 * i + 3)
        z[i] = py_key_normal(k.latency, i)
    kept = ~(u5[:, 2] < p.loss_probability)
    reordered = u5[:, 4] < p.reorder_probability
    next_slot = np.ceil(send_s / cycle) * cycle
    u_cycle = (next_slot - send_s) / cycle
    delay = delivery_delay_s(p, sizes + 4, u_cycle, z, reordered=reordered)
    expected = {i: float(send_s[i] + delay[i]) for i in np.flatnonzero(kept)}

    assert set(arrived) == set(expected)
    assert 0 < reordered[kept].sum() < kept.sum()  # both branches compared
    for i, t in expected.items():
        assert arrived[i] == pytest.approx(t, abs=1e-9)


def test_scalar_and_array_paths_agree_exactly() -> None:
    p = ChannelParams(bit_rate_bps=2400.0, overhead_bits=37, latency_s=0.013, jitter_s=0.007)
    sizes = list(range(0, 300))
    assert [airtime_s(p, k) for k in sizes] == np.asarray(airtime_s(p, np.array(sizes))).tolist()
    zs = np.random.default_rng(0).standard_normal(1000) * 3
    assert [propagation_delay_s(p, float(z)) for z in zs] == np.asarray(propagation_delay_s(p, zs)).tolist()


def test_per_run_overrides_equal_changed_parameters() -> None:
    """latency_s / jitter_s / bit_error_rate arrays give what a ChannelParams with those values gives."""
    base = ChannelParams(bit_rate_bps=9600.0, cycle_s=0.05, latency_s=0.03, jitter_s=0.01, overhead_bits=8)
    g = np.random.default_rng(3)
    n = 50
    lat, sd = g.uniform(0.02, 0.08, n), g.uniform(0.0, 0.02, n)
    u, z, size = g.random(n), g.standard_normal(n), g.integers(0, 30, n)
    got = delivery_delay_s(base, size, u, z, latency_s=lat, jitter_s=sd)
    one_by_one = [
        delivery_delay_s(base.replace(latency_s=lat[i], jitter_s=sd[i]), int(size[i]), u[i], z[i])
        for i in range(n)
    ]
    np.testing.assert_allclose(got, one_by_one, rtol=0, atol=1e-15)
    ber = np.array([0.0, 1e-6, 1e-3, 0.5, 1.0])
    got_p = corruption_probability(base, 10, bit_error_rate=ber)
    np.testing.assert_allclose(
        got_p, [corruption_probability(base.replace(bit_error_rate=b), 10) for b in ber]
    )
    assert np.asarray(got_p)[-1] == 1.0 and corruption_probability(base.replace(bit_error_rate=1.0), 0) == 0.0
    with pytest.raises(LinkError, match="latency_s"):
        delivery_delay_s(base, 10, 0.5, 0.0, latency_s=np.array([0.01, -0.01]))
    with pytest.raises(LinkError, match="bit_error_rate"):
        corruption_probability(base, 10, bit_error_rate=1.5)


def test_mean_delivery_delay_matches_simulation() -> None:
    # jitter comparable to latency: the clip at 0 matters, so the clipped-normal mean is checked.
    p = ChannelParams(
        bit_rate_bps=2400.0,
        cycle_s=0.2,
        latency_s=0.01,
        jitter_s=0.02,
        reorder_probability=0.2,
        reorder_delay_s=0.05,
        overhead_bits=32,
    )
    n, n_bytes = 20000, 10
    layout = np.random.default_rng(5)
    send_s = np.arange(n) * 1.0 + layout.random(n)  # phase in the cycle uniform
    ch = SimChannel(p, keys(6))
    for i in range(n):
        ch.send(frame(i, n_bytes), float(send_s[i]))
    arrived = {index(f): t for t, f in drain(ch)}
    delays = np.array([arrived[i] - send_s[i] for i in range(n)])
    sd = delays.std(ddof=1) / math.sqrt(n)
    within(delays.mean(), float(mean_delivery_delay_s(p, n_bytes)), sd)
    # The unclipped mean (latency alone) would be clearly off: the clip is really modelled.
    naive = 0.1 + float(airtime_s(p, n_bytes)) + 0.01 + 0.2 * 0.05
    assert abs(delays.mean() - naive) > Z * sd
    # Never earlier than airtime (no negative wait or latency).
    assert delays.min() >= float(airtime_s(p, n_bytes)) - 1e-12


# --------------------------------------------------------------------------
# Loss, duplicates, bursts, corruption


def test_independent_loss_rate() -> None:
    p = ChannelParams(bit_rate_bps=1e6, loss_probability=0.1)
    n = 20000
    ch, out = send_all(p, seed=1, n=n)
    s = ch.stats
    within(s.lost / n, 0.1, math.sqrt(0.1 * 0.9 / n))
    assert s.sent == n and len(out) == s.delivered == n - s.lost
    assert s.sent_in_burst == 0


def test_duplicate_rate_and_copies() -> None:
    p = ChannelParams(bit_rate_bps=1e6, duplicate_probability=0.05, latency_s=0.001)
    n = 20000
    ch, out = send_all(p, seed=2, n=n)
    s = ch.stats
    within(s.duplicated / n, 0.05, math.sqrt(0.05 * 0.95 / n))
    counts = np.bincount([index(f) for _, f in out], minlength=n)
    assert set(np.unique(counts)) == {1, 2}
    assert int((counts == 2).sum()) == s.duplicated
    assert s.delivered == n + s.duplicated


def test_gilbert_elliott_stationary_rates_and_bursts() -> None:
    enter, leave, h = 0.02, 0.1, 0.6
    p = ChannelParams(
        bit_rate_bps=1e6,
        burst_enter_probability=enter,
        burst_exit_probability=leave,
        burst_loss_probability=h,
    )
    n = 40000
    ch, _ = send_all(p, seed=3, n=n)
    s = ch.stats
    pi = enter / (enter + leave)
    lam = 1.0 - enter - leave
    assert p.burst_bad_fraction == pytest.approx(pi)
    within(s.sent_in_burst / n, pi, markov_mean_sd(pi, lam, n))
    # Loss X_t = B_t L_t: Var X = πh(1−πh), Cov(X_t, X_t+k) = h² π(1−π) λ^k.
    q = pi * h
    var_n = q * (1 - q) + 2 * h * h * pi * (1 - pi) * lam / (1 - lam)
    within(s.lost / n, q, math.sqrt(var_n / n))
    assert stationary_loss_probability(p) == pytest.approx(q)

    # Losses come in bursts: with h = 1 a run of losses is a stay in the bad state,
    # geometric with mean 1 / p_exit (independent losses at the same rate: ~1.2).
    ch1, out1 = send_all(p.replace(burst_loss_probability=1.0), seed=4, n=n)
    got = np.zeros(n, dtype=bool)
    got[[index(f) for _, f in out1]] = True
    lost = ~got
    edges = np.diff(np.concatenate(([0], lost.astype(int), [0])))
    runs = np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)
    assert runs.sum() == ch1.stats.lost
    within(runs.mean(), 1 / leave, math.sqrt(1 - leave) / leave / math.sqrt(runs.size))


def test_independent_and_burst_loss_combined() -> None:
    p = ChannelParams(
        bit_rate_bps=1e6,
        loss_probability=0.05,
        burst_enter_probability=0.01,
        burst_exit_probability=0.2,
        burst_loss_probability=0.5,
    )
    n = 40000
    ch, _ = send_all(p, seed=12, n=n)
    pi = 0.01 / 0.21
    lam = 1 - 0.21
    q = 1 - 0.95 * (1 - pi * 0.5)
    assert stationary_loss_probability(p) == pytest.approx(q)
    var_n = q * (1 - q) + 2 * (0.95 * 0.5) ** 2 * pi * (1 - pi) * lam / (1 - lam)
    within(ch.stats.lost / n, q, math.sqrt(var_n / n))


def test_corruption_rate_and_flipped_bits() -> None:
    ber, n_bytes, n = 1e-3, 20, 20000
    p = ChannelParams(bit_rate_bps=1e6, bit_error_rate=ber)
    ch, out = send_all(p, seed=4, n=n, n_bytes=n_bytes)
    s = ch.stats
    expected = 1 - (1 - ber) ** (8 * n_bytes)
    assert corruption_probability(p, n_bytes) == pytest.approx(expected, rel=1e-12)
    within(s.corrupted / s.delivered, expected, math.sqrt(expected * (1 - expected) / s.delivered))
    # The delivered copies really differ: the number of changed frames is the count,
    # and the flipped bits average 8 n BER per frame (independent bit flips).
    originals = [frame(i, n_bytes) for i in range(n)]
    flips = np.array(
        [
            int.from_bytes(bytes(a ^ b for a, b in zip(f, originals[i], strict=True)), "big").bit_count()
            for i, (_, f) in enumerate(out)
        ]
    )
    assert int((flips > 0).sum()) == s.corrupted
    bits = 8 * n_bytes
    within(flips.mean(), bits * ber, math.sqrt(bits * ber * (1 - ber) / n))


def test_each_delivered_copy_is_corrupted_independently() -> None:
    ber, n_bytes, n = 2e-3, 16, 10000
    p = ChannelParams(bit_rate_bps=1e6, bit_error_rate=ber, duplicate_probability=1.0)
    ch, out = send_all(p, seed=13, n=n, n_bytes=n_bytes)
    s = ch.stats
    assert s.delivered == 2 * n
    expected = float(corruption_probability(p, n_bytes))
    within(s.corrupted / s.delivered, expected, math.sqrt(expected * (1 - expected) / s.delivered))
    # No latency, 10 ms spacing: the copy arrives right after its original.
    pairs = list(zip(out[0::2], out[1::2], strict=True))
    assert all(t2 > t1 for (t1, _), (t2, _) in pairs)
    # Independent hits: the copies differ unless both are clean, 1 − (1 − p)², up to the
    # negligible chance (~p²/128) that both are hit at exactly the same bits.
    differ = sum(a != b for (_, a), (_, b) in pairs) / n
    p_differ = 1 - (1 - expected) ** 2
    within(differ, p_differ, math.sqrt(p_differ * (1 - p_differ) / n))


def test_no_bit_errors_without_ber() -> None:
    p = BUSY.replace(bit_error_rate=0.0)
    ch, out = send_all(p, seed=5, n=3000, spacing_s=0.03)
    assert ch.stats.corrupted == 0
    assert all(f == frame(index(f)) for _, f in out)
    assert corruption_probability(p, np.array([0, 10, 1000])).tolist() == [0.0, 0.0, 0.0]


# --------------------------------------------------------------------------
# Cycle slots, order


def test_cycle_slots_one_frame_per_slot() -> None:
    # 10 bytes at 2400 bit/s: airtime 1/30 s; slots every 0.25 s (loop, SPEC §5).
    p = ChannelParams(bit_rate_bps=2400.0, cycle_s=0.25)
    air = 80 / 2400
    ch = SimChannel(p, keys(0))
    sends = [0.01, 0.02, 0.03, 0.6, 1.25]
    for i, t in enumerate(sends):
        ch.send(frame(i, 10), t)
    got = drain(ch)
    # three frames at once take three slots; 0.6 finds 0.75 taken -> 1.0; 1.25 is on a slot.
    departures = [0.25, 0.5, 0.75, 1.0, 1.25]
    assert [index(f) for _, f in got] == [0, 1, 2, 3, 4]
    np.testing.assert_allclose([t for t, _ in got], np.array(departures) + air, atol=1e-12)


def test_cycle_slots_one_per_slot_even_with_zero_airtime() -> None:
    # Empty frames and no overhead take no time on the medium: only the slot rule spaces them.
    p = ChannelParams(bit_rate_bps=2400.0, cycle_s=0.25)
    ch = SimChannel(p, keys(0))
    for t in (0.0, 0.0, 0.1):
        ch.send(b"", t)
    assert airtime_s(p, 0) == 0.0
    np.testing.assert_allclose([t for t, _ in drain(ch)], [0.0, 0.25, 0.5], atol=1e-12)


def test_cycle_slots_with_phase_and_long_airtime() -> None:
    # 10 bytes at 100 bit/s = 0.8 s on the medium, longer than the 0.25 s cycle:
    # the next frame waits for the medium, then for the next slot.
    p = ChannelParams(bit_rate_bps=100.0, cycle_s=0.25)
    ch = SimChannel(p, keys(0), slot_phase_s=0.1)
    ch.send(frame(0, 10), 0.0)  # slot 0.1, on air until 0.9
    ch.send(frame(1, 10), 0.05)  # medium free at 0.9 -> slot 1.1, arrives 1.9
    got = drain(ch)
    np.testing.assert_allclose([t for t, _ in got], [0.9, 1.9], atol=1e-12)


def test_frames_keep_send_order_without_reordering() -> None:
    # Jitter (sd 50 ms) far larger than the 5 ms spacing: still first in, first out,
    # a duplicate right after its original.
    p = ChannelParams(
        bit_rate_bps=1e6, latency_s=0.05, jitter_s=0.05, loss_probability=0.1, duplicate_probability=0.2
    )
    ch, out = send_all(p, seed=9, n=5000, spacing_s=0.005)
    idx = [index(f) for _, f in out]
    assert idx == sorted(idx)
    assert ch.stats.reordered == 0 and ch.stats.duplicated > 0


def test_reordering_only_with_reorder_probability() -> None:
    p = ChannelParams(bit_rate_bps=1e6, latency_s=0.01, reorder_probability=0.1, reorder_delay_s=0.05)
    n = 5000
    ch, out = send_all(p, seed=10, n=n)
    idx = np.array([index(f) for _, f in out])
    assert np.any(np.diff(idx) < 0)
    within(ch.stats.reordered / n, 0.1, math.sqrt(0.1 * 0.9 / n))
    # A held-back frame is late by reorder_delay_s; the others still keep their order.
    held = ch.stats.reordered
    arrivals = {index(f): t for t, f in out}
    late = [i for i in range(n) if arrivals[i] - i * 0.01 > 0.01 + 0.05 - 1e-9]
    assert len(late) == held
    on_time = [i for i in idx if i not in set(late)]
    assert on_time == sorted(on_time)


def test_receive_pops_each_frame_once() -> None:
    p = ChannelParams(bit_rate_bps=1e6, latency_s=0.1)
    ch = SimChannel(p, keys(0))
    for i in range(3):
        ch.send(frame(i), 0.01 * i)
    assert ch.receive(0.05) == []
    assert ch.in_flight() == 3
    first = ch.receive(0.105)
    assert [index(f) for f in first] == [0]
    rest = ch.receive(10.0)
    assert [index(f) for f in rest] == [1, 2]
    assert ch.receive(10.0) == []
    assert ch.next_arrival_s() is None
    assert ch.stats.delivered == 3


def test_bad_inputs_raise() -> None:
    ch = SimChannel(ChannelParams(bit_rate_bps=1e6), keys(0))
    ch.send(b"x", 1.0)
    with pytest.raises(LinkError, match="backwards"):
        ch.send(b"y", 0.5)
    with pytest.raises(LinkError, match="bytes"):
        ch.send("text", 2.0)  # type: ignore[arg-type]
    with pytest.raises(LinkError, match="finite"):
        ch.send(b"z", math.nan)
    p = ChannelParams(bit_rate_bps=1e6, cycle_s=0.1)
    with pytest.raises(LinkError, match="u_cycle"):
        delivery_delay_s(p, 10, 1.5, 0.0)
    with pytest.raises(LinkError, match="n_bytes"):
        airtime_s(p, -1)
    with pytest.raises(LinkError, match="LinkStreams"):
        SimChannel(p, np.random.default_rng(0))  # type: ignore[arg-type]
    with pytest.raises(LinkError, match="outage"):
        SimChannel(p, keys(0), outages=[(2.0, 1.0)])
    with pytest.raises(LinkError, match="outages"):
        SimChannel(p, keys(0), outages=3)
    with pytest.raises(LinkError, match="64-bit key"):
        LinkStreams(loss=-1, latency=0, corrupt=0, faults=0, flips=0)
    assert issubclass(LinkError, RailstopError)


# --------------------------------------------------------------------------
# Parameters and presets


@pytest.mark.parametrize(
    ("changes", "field", "value"),
    [
        ({"bit_rate_bps": 0.0}, "bit_rate_bps", 0.0),
        ({"latency_s": -0.01}, "latency_s", -0.01),
        ({"loss_probability": 1.5}, "loss_probability", 1.5),
        ({"jitter_s": math.inf}, "jitter_s", math.inf),
        ({"overhead_bits": -8}, "overhead_bits", -8),
    ],
)
def test_params_reject_bad_values(changes: dict[str, float], field: str, value: float) -> None:
    with pytest.raises(ConfigError) as info:
        ChannelParams(**{"bit_rate_bps": 2400.0, **changes})
    assert info.value.field == field
    assert info.value.value == value


def test_params_reject_unknown_key_and_replace_validates() -> None:
    with pytest.raises(ConfigError, match="unknown key") as info:
        ChannelParams(bit_rate_bps=2400.0, latency_ms=5.0)
    assert info.value.field == "latency_ms"
    with pytest.raises(ConfigError):
        BUSY.replace(cycle_s=-1.0)


def test_presets_load_with_spec_values() -> None:
    media = load_media()
    assert set(media) == {"loop", "transponder", "radio", "cbtc-radio"}
    loop, tp, radio = media["loop"], media["transponder"], media["radio"]
    # SPEC §4 train radio (assumptions): tens of ms, rarer losses than the TASC radio, no bursts
    cbtc = media["cbtc-radio"]
    assert 0.01 <= cbtc.latency_s <= 0.08 and cbtc.loss_probability < radio.loss_probability
    assert cbtc.burst_bad_fraction == 0.0
    # SPEC §5 table
    assert loop.bit_rate_bps == 2400.0 and 0.2 <= loop.cycle_s <= 0.25
    assert tp.bit_rate_bps == 64000.0 and 0.01 <= tp.cycle_s <= 0.05
    assert 1e6 <= radio.bit_rate_bps <= 500e6 and radio.cycle_s == 0.0
    # tens of ms; the standard disturbance set's 2 % radio loss, plus bursts
    assert 0.02 <= radio.latency_s <= 0.08
    assert radio.loss_probability == 0.02 and radio.burst_bad_fraction > 0.0
    assert media_preset("loop") == loop
    assert load_media("media") == media
    # A ~10-byte telegram fits in one loop cycle and in one transponder cycle.
    assert airtime_s(loop, 10) < loop.cycle_s and airtime_s(tp, 10) < tp.cycle_s


def test_unknown_preset_names_the_medium() -> None:
    with pytest.raises(ConfigError, match="unknown medium") as info:
        media_preset("carrier-pigeon")
    assert info.value.value == "carrier-pigeon"
    assert "media.toml" in info.value.source


@pytest.mark.parametrize(
    ("body", "field", "value"),
    [
        ("[radio]\nbit_rate_bps = 1e6\nlatency_s = -0.1\n", "radio.latency_s", -0.1),
        ("[loop]\nbit_rate_bps = 2400.0\nloss_probability = 1.5\n", "loop.loss_probability", 1.5),
        ("[loop]\nbit_rate_bps = 0.0\n", "loop.bit_rate_bps", 0.0),
        ("[loop]\nbit_rate_bps = -2400\n", "loop.bit_rate_bps", -2400),
        ("[loop]\nbit_rate_bps = 'fast'\n", "loop.bit_rate_bps", "fast"),
        ("[loop]\nbit_rate_bps = 2400.0\nlatncy_s = 0.01\n", "loop.latncy_s", None),
        ("[loop]\ncycle_s = 0.25\n", "loop.bit_rate_bps", None),
        ("loop = 3\n", "loop", 3),
    ],
)
def test_bad_media_file_names_file_field_value(tmp_path, body: str, field: str, value: object) -> None:
    path = tmp_path / "bad-media.toml"
    path.write_text("# a media file\n" + body, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_media(path)
    err = info.value
    assert err.source == str(path)
    assert err.field == field
    assert err.value == value
    assert str(path) in str(err) and field in str(err)


def test_bad_media_file_syntax_missing_and_empty(tmp_path) -> None:
    bad = tmp_path / "syntax.toml"
    bad.write_text("[loop\nbit_rate_bps = 1\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="toml syntax"):
        load_media(bad)
    with pytest.raises(ConfigError, match="no such file"):
        load_media(tmp_path / "absent.toml")
    empty = tmp_path / "empty.toml"
    empty.write_text("# nothing\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="at least one"):
        load_media(empty)


def test_own_media_file_loads(tmp_path) -> None:
    path = tmp_path / "media.toml"
    path.write_text("[slow]\nbit_rate_bps = 300.0\ncycle_s = 0.5\noverhead_bits = 8\n", encoding="utf-8")
    p = media_preset("slow", path)
    assert p == ChannelParams(bit_rate_bps=300.0, cycle_s=0.5, overhead_bits=8)


def test_safety_layer_rejects_what_the_channel_damages() -> None:
    """Loop preset with a raised BER and duplicates: the EN 50159 receiver rejects every damaged copy."""
    from railstop.link.safety import Delivered, SafeReceiver, SafeSender

    p = media_preset("loop").replace(bit_error_rate=1e-3, duplicate_probability=0.05, loss_probability=0.05)
    tx = SafeSender(1, 2, category=1)
    rx = SafeReceiver(2, 1, category=1, max_age_s=1.0, timeout_s=2.0)
    ch = SimChannel(p, keys(21))
    n = 3000
    sent = []
    for i in range(n):
        f = tx.wrap(i.to_bytes(4, "big"), 0.3 * i)
        sent.append(f)
        ch.send(f, 0.3 * i)
    originals = set(sent)
    delivered: list[int] = []
    clean_copies = 0
    for t, f in drain(ch):
        clean_copies += f in originals
        result = rx.accept(f, t)
        if isinstance(result, Delivered):
            assert f in originals  # nothing damaged gets through
            delivered.append(result.seq)
    s = ch.stats
    assert s.corrupted > 0 and s.duplicated > 0 and s.lost > 0
    assert rx.counts["corrupt"] == s.corrupted
    assert rx.counts["delivered"] + rx.counts["repeated"] == clean_copies
    assert delivered == sorted(set(delivered))
    assert rx.deletions == delivered[-1] - len(delivered)


# --------------------------------------------------------------------------
# Counter-based streams, outages, the stop model's medium


def test_a_frames_fate_depends_on_its_counter_only() -> None:
    """Frame c's loss, corruption and jitter come from counter c of the link's streams: the same
    whatever the send times, and independent of the other direction's traffic (DESIGN rule 7)."""
    p = ChannelParams(
        bit_rate_bps=1e6, latency_s=0.05, jitter_s=0.01, loss_probability=0.2, bit_error_rate=2e-3
    )
    a, b = SimChannel(p, keys(4)), SimChannel(p, keys(4))
    fate_a = [a.send(frame(i), 1.0 * i) for i in range(500)]  # isolated: no queueing, no FIFO floor
    fate_b = [b.send(frame(i), 7.0 + 3.0 * i) for i in range(500)]
    assert [x is None for x in fate_a] == [x is None for x in fate_b]
    delays_a = [x - 1.0 * i for i, x in enumerate(fate_a) if x is not None]
    delays_b = [x - (7.0 + 3.0 * i) for i, x in enumerate(fate_b) if x is not None]
    np.testing.assert_allclose(delays_a, delays_b, rtol=0, atol=1e-12)
    assert [f for _, f in drain(a)] == [f for _, f in drain(b)]  # the same bits flipped
    assert 0 < a.stats.lost < 500 and a.stats.corrupted > 0
    # Another link (another train, direction or dwell) draws other numbers.
    c = SimChannel(p, LinkStreams.for_link(4, Stream.DOOR_LINK, 98))
    assert [c.send(frame(i), 1.0 * i) is None for i in range(500)] != [x is None for x in fate_a]


def test_an_outage_loses_every_frame_sent_in_it_and_nothing_else() -> None:
    p = ChannelParams(bit_rate_bps=1e6, latency_s=0.01)
    ch = SimChannel(p, keys(1), outages=[(1.0, 2.0), (5.0, math.inf)])
    times = [0.5, 0.999, 1.0, 1.5, 1.999, 2.0, 4.9, 5.0, 60.0]
    got = [ch.send(frame(i), t) for i, t in enumerate(times)]
    assert [g is None for g in got] == [False, False, True, True, True, False, False, True, True]
    s = ch.stats
    assert s.sent == 9 and s.lost == s.lost_in_outage == 5
    assert [index(f) for _, f in drain(ch)] == [0, 1, 5, 6]
    # A frame sent in the outage takes no counter's draws away from the others: frame 5 meets
    # counter 5's numbers as it would without the outage.
    free = SimChannel(p, keys(1))
    assert [free.send(frame(i), t) for i, t in enumerate(times)][5] == got[5]


def test_bit_flips_are_exact_for_a_high_error_rate() -> None:
    """The first flip by inversion and geometric gaps after it: with BER 0.1 on 8-byte frames
    the number of flipped bits per copy is Binomial(64, 0.1) (mean and variance) and every bit
    position is hit equally often."""
    ber, n_bytes, n = 0.1, 8, 20000
    p = ChannelParams(bit_rate_bps=1e6, bit_error_rate=ber)
    _, out = send_all(p, seed=3, n=n, n_bytes=n_bytes)
    base = [frame(i, n_bytes) for i in range(n)]
    flips = np.array(
        [
            [((a ^ b) >> (7 - j)) & 1 for a, b in zip(f, base[i], strict=True) for j in range(8)]
            for i, (_, f) in enumerate(out)
        ]
    )
    per = flips.sum(axis=1)
    bits = 8 * n_bytes
    within(per.mean(), bits * ber, math.sqrt(bits * ber * (1 - ber) / n))
    within(per.var(), bits * ber * (1 - ber), bits * ber * (1 - ber) * math.sqrt(2.0 / n) * 1.5)
    hits = flips.mean(axis=0)
    assert np.all(np.abs(hits - ber) < Z * math.sqrt(ber * (1 - ber) / n))
    assert SimChannel(p.replace(bit_error_rate=1.0), keys(0)).send(b"\x00\xff", 0.0) is not None


def test_the_stop_models_attempts_meet_the_same_fate_on_this_medium() -> None:
    """One medium (issue: one link): the stop kernel's telegram attempts of a campaign run and this
    medium's frames of the same run's streams (``LinkStreams.for_run``) are lost, corrupted,
    delayed and held back alike, attempt by attempt, on a radio with loss, jitter, bit errors,
    bursts (stop model 13) and reordering."""
    from railstop.config import default_line, default_vehicle
    from railstop.config.disturbances import DisturbanceSet, draw_scenario
    from railstop.model.build import KernelModel
    from railstop.model.records import (
        KP_AIRTIME,
        KP_DT,
        KP_FRAME_BITS,
        LA_ARRIVAL,
        LA_CORRUPT,
        LA_LOST,
        LA_STEP,
        SC_BER,
        SC_BURST_ENTER,
        SC_BURST_EXIT,
        SC_BURST_LOSS,
        SC_JITTER,
        SC_LATENCY,
        SC_LOSS,
        SC_REORDER,
    )
    from railstop.model.run import model_draws, run_kernel
    from railstop.streams import RunStreams

    line, vehicle = default_line(), default_vehicle()
    station = line.station("Riverside")
    assert media_preset(station.tasc.medium).cycle_s == 0.0
    bad_radio = DisturbanceSet.from_dict(
        {
            "radio_latency_ms": {"uniform": [40.0, 120.0]},
            "radio_loss_probability": 0.2,
            "radio_jitter_ms": {"fixed": 30.0},
            "radio_bit_error_rate": {"fixed": 0.002},
            "radio_burst_enter_probability": 0.05,
            "radio_burst_exit_probability": 0.3,
            "radio_burst_loss_probability": 0.8,
            "radio_reorder_probability": 0.1,
        },
        name="bad-radio",
    )
    model = KernelModel.create(
        station=station, vehicle=vehicle, controller="tasc-pwm", form=None, dt_s=0.01, max_time_s=150.0
    )
    checked = {"lost": 0, "corrupt": 0, "held": 0, "frames": 0, "in_burst": 0, "reordered": 0}
    for seed, run in ((3, 0), (3, 17), (11, 2**40 + 5)):
        scenario, _ = draw_scenario(bad_radio, station, vehicle, RunStreams.for_runs(seed, run, 1))
        _, _, rec = run_kernel(model, scenario, seed=seed, first_run=run, record=True)
        assert rec is not None
        sc = model_draws(model, scenario)[0][0]
        params = media_preset(station.tasc.medium).replace(
            latency_s=float(sc[SC_LATENCY]),
            jitter_s=float(sc[SC_JITTER]),
            loss_probability=float(sc[SC_LOSS]),
            bit_error_rate=float(sc[SC_BER]),
            burst_enter_probability=float(sc[SC_BURST_ENTER]),
            burst_exit_probability=float(sc[SC_BURST_EXIT]),
            burst_loss_probability=float(sc[SC_BURST_LOSS]),
            reorder_probability=float(sc[SC_REORDER]),
            duplicate_probability=0.0,  # not in the stop model: the receiver drops a copy anyway
        )
        assert params.reorder_delay_s > 0.0
        n_bytes = int(model.kp[KP_FRAME_BITS]) // 8
        assert float(airtime_s(params, n_bytes)) == model.kp[KP_AIRTIME]
        ch = SimChannel(params, LinkStreams.for_run(seed, run))
        floor = -math.inf  # the medium keeps frames in order; the kernel's receiver drops overtaken ones
        for a in rec.attempts:
            before = ch.stats
            arrival = ch.send(bytes(n_bytes), a[LA_STEP] * model.kp[KP_DT])
            checked["in_burst"] += ch.stats.sent_in_burst > before.sent_in_burst
            assert (arrival is None) == bool(a[LA_LOST])
            if arrival is None:
                checked["lost"] += 1
                continue
            assert (ch.stats.corrupted > before.corrupted) == bool(a[LA_CORRUPT])
            checked["corrupt"] += bool(a[LA_CORRUPT])
            if ch.stats.reordered > before.reordered:  # held back alike, out of the medium's order
                assert arrival == a[LA_ARRIVAL]
                checked["reordered"] += 1
            else:
                assert arrival == max(a[LA_ARRIVAL], floor)
                checked["held"] += arrival > a[LA_ARRIVAL]
                floor = arrival
            checked["frames"] += 1
    assert min(checked.values()) > 0, checked  # every path compared
