"""A seeded simulated train↔platform medium (SPEC §5): airtime, poll cycle, latency, loss, errors.

SPEC §5 compares three media: the wayside loop (FSK, 2400 bit/s, 200–250 ms
cycle, CRC-16), the transponder (FSK, 64 kbit/s, 10–50 ms cycle, CRC-16) and
short-range radio (1–500 Mbit/s, tens of ms latency, interference). One
:class:`~railstop.config.media.ChannelParams` describes any of them; the embedded presets live in
``railstop/data/media.toml`` (``config.media.load_media``, :func:`media_preset`).

The delay model (one model, two drivers)
----------------------------------------
A frame of ``n`` bytes sent at time t on an idle channel arrives at::

    t + wait + airtime + propagation (+ reorder_delay_s if held back)

* ``wait``: 0 when ``cycle_s == 0``; otherwise the frame leaves at the next
  slot of the poll cycle (SPEC §5: the loop and the transponder are polled
  every 200–250 ms / 10–50 ms), so ``wait = u · cycle_s`` with ``u`` the
  phase of t in the cycle, uniform in [0, 1) when sends are unrelated to the
  cycle (mean ``cycle_s / 2``).
* ``airtime = (8 n + overhead_bits) / bit_rate_bps``.
* ``propagation = max(0, latency_s + jitter_s · z)``, z standard normal:
  **jitter_s is the standard deviation** of a normal around ``latency_s``,
  clipped at 0 (not resampled) so the latency is never negative. Its mean is
  ``L Φ(L/σ) + σ φ(L/σ)`` (exactly ``latency_s`` when the clip never bites).

The pure functions :func:`airtime_s`, :func:`propagation_delay_s`,
:func:`delivery_delay_s`, :func:`mean_delivery_delay_s`,
:func:`corruption_probability` and :func:`stationary_loss_probability` work
on numpy arrays, for a vectorised Monte Carlo engine that draws its own
(counter-based) uniforms and normals; ``latency_s``, ``jitter_s`` and
``bit_error_rate`` may be given per run (keyword arrays) to override the
medium's values, e.g. a radio latency drawn from a disturbance set. :class:`SimChannel`, the event-by-event
driver, computes its arrival times with the same functions; on top of that it
models queueing: one frame on the medium at a time, at most one frame per
cycle slot, and first-in first-out delivery (a frame never overtakes an
earlier one unless it is *reordered*: held back by ``reorder_delay_s``).

Loss, duplication, corruption
-----------------------------
* independent loss with ``loss_probability`` per frame;
* burst loss, Gilbert–Elliott: a two-state (good/bad) Markov chain advanced
  once per frame sent (good→bad with ``burst_enter_probability``, bad→good
  with ``burst_exit_probability``; the channel starts good); a frame sent in
  the bad state is lost with ``burst_loss_probability``. Stationary
  π_bad = p_enter / (p_enter + p_exit);
* a delivered frame is duplicated with ``duplicate_probability``: the copy is
  transmitted again straight after the original (one more airtime, same slot)
  and arrives one airtime after it;
* each delivered copy has every bit flipped independently with
  ``bit_error_rate`` — the receiver's CRC / MAC must catch it (SPEC §5 CRC-16;
  the EN 50159 safety layer). Errors in the ``overhead_bits`` (preamble,
  sync) are not modelled as corruption: a receiver that loses sync drops the
  frame, which is loss;
* an outage (fault data: a radio dead from ``start_s`` to ``end_s``) loses
  every frame sent in it; such a frame never takes the medium nor advances the
  burst chain (the transmitter is dead), and is counted as lost and as
  ``lost_in_outage``. The stop kernel's outage (``SC_OUTAGE_*``) is the same
  rule.

Randomness (DESIGN rule 7): counter-based streams
--------------------------------------------------
A medium draws from the project's counter-based streams (``railstop.streams``),
never from a generator's sequence: frame ``c`` (the c-th ``send()``, counted
from 0 whatever its fate) uses the numbers of counter ``c``, so what happens
to a frame depends on (seed, link, c) only, not on the draws of the frames
before it nor on the other direction's. :class:`LinkStreams` holds a link's
keys, one per role:

* ``loss``: ``uniform(c)`` below ``loss_probability`` loses the frame;
* ``latency``: ``normal(c)`` is the jitter's z;
* ``corrupt``: ``uniform(2c)`` below the frame's corruption probability
  corrupts the first copy, ``uniform(2c + 1)`` places its first flipped bit;
* ``faults``: ``uniform(4c)`` the Gilbert–Elliott transition, ``4c + 1`` the
  loss while bad, ``4c + 2`` duplication, ``4c + 3`` reordering;
* ``flips``: the key ``stream_key(flips, 2c + j)`` gives copy j's further
  flipped bits (counter 0 whether the duplicate, j = 1, is corrupted, 1 its
  first flipped bit, 2.. the gaps to the next flip).

The first three are the stop model's radio streams: :meth:`LinkStreams.for_run`
gives a campaign run's keys, and for a medium without a poll cycle, bursts,
duplication or reordering the stop kernel's telegram attempt ``c`` and this
medium's frame ``c`` are lost, corrupted and delayed alike (a test compares
them attempt by attempt). :meth:`LinkStreams.for_link` gives any other link's
keys from (seed, owner stream, identity), e.g. the door link of a train's n-th
dwell. The bit flips are exact for independent errors of rate BER per bit:
given at least one flip, the first flipped bit J has P(J = j) ∝ (1 − BER)^j
BER, drawn by inverting its distribution, and the gaps between flips are
geometric. Every draw is a few integer operations in Python
(``streams.py_key_uniform``), bit-identical to the compiled model's.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from railstop.config.media import MEDIA_FILE, ChannelParams, load_media
from railstop.errors import ConfigError, RailstopError
from railstop.streams import (
    Stream,
    py_fold,
    py_key_normal,
    py_key_uniform,
    py_seed_key,
    py_stream_key,
)

FloatArray = NDArray[np.float64]

# A float time on a slot boundary (e.g. 0.5 s with a 0.25 s cycle) may come out
# as k ± 1e-16 cycles; within this many cycles it counts as on the slot.
_SLOT_EPS = 1e-9


class LinkError(RailstopError):
    """A link was used wrongly: bad frame, time going backwards, oversize datagram..."""


# --------------------------------------------------------------------------
# Pure, vectorised model


def _out(x: NDArray[Any]) -> float | FloatArray:
    return float(x) if x.ndim == 0 else x.astype(np.float64, copy=False)


def _n_bytes(n_bytes: ArrayLike) -> NDArray[Any]:
    n = np.asarray(n_bytes)
    if n.dtype.kind not in "iuf" or np.any(n < 0) or not np.all(np.isfinite(n)):
        raise LinkError(f"n_bytes must be non-negative byte counts (got {n_bytes!r})")
    return n


def airtime_s(params: ChannelParams, n_bytes: ArrayLike) -> float | FloatArray:
    """Time on the medium of a frame: (8 · n_bytes + overhead_bits) / bit_rate_bps."""
    if type(n_bytes) is int and n_bytes >= 0:  # scalar fast path (SimChannel), same float64 operations
        return (8.0 * n_bytes + params.overhead_bits) / params.bit_rate_bps
    n = _n_bytes(n_bytes)
    return _out((8.0 * n + params.overhead_bits) / params.bit_rate_bps)


def _override(name: str, value: ArrayLike | None, default: float, hi: float = math.inf) -> Any:
    """A per-run value replacing a parameter (e.g. a drawn radio latency), checked like the parameter."""
    if value is None:
        return default
    v = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(v)) or np.any((v < 0.0) | (v > hi)):
        raise LinkError(f"{name} must lie in [0, {hi}] (got {value!r})")
    return v


def propagation_delay_s(
    params: ChannelParams,
    z_jitter: ArrayLike,
    *,
    latency_s: ArrayLike | None = None,
    jitter_s: ArrayLike | None = None,
) -> float | FloatArray:
    """Propagation + processing delay for standard-normal draws z: max(0, latency + jitter · z).

    ``latency_s`` / ``jitter_s``, if given (scalars or per-run arrays), replace
    the parameters' values, e.g. a radio latency drawn per run by a campaign.
    """
    if type(z_jitter) is float and latency_s is None and jitter_s is None:
        # scalar fast path (SimChannel), the same float64 operations as below
        return max(0.0, params.latency_s + params.jitter_s * z_jitter)
    lat = _override("latency_s", latency_s, params.latency_s)
    sd = _override("jitter_s", jitter_s, params.jitter_s)
    z = np.asarray(z_jitter, dtype=np.float64)
    return _out(np.asarray(np.maximum(0.0, lat + sd * z)))


def mean_propagation_delay_s(params: ChannelParams) -> float:
    """E[max(0, L + σ Z)] = L Φ(L/σ) + σ φ(L/σ) (the mean of a normal clipped at 0)."""
    lat, sd = params.latency_s, params.jitter_s
    if sd == 0.0:
        return lat
    a = lat / sd
    cdf = 0.5 * (1.0 + math.erf(a / math.sqrt(2.0)))
    pdf = math.exp(-0.5 * a * a) / math.sqrt(2.0 * math.pi)
    return lat * cdf + sd * pdf


def delivery_delay_s(
    params: ChannelParams,
    n_bytes: ArrayLike,
    u_cycle: ArrayLike,
    z_jitter: ArrayLike,
    *,
    reordered: ArrayLike = False,
    latency_s: ArrayLike | None = None,
    jitter_s: ArrayLike | None = None,
) -> float | FloatArray:
    """Send-to-arrival delay of a frame on an idle channel, from given draws.

    ``u_cycle`` in [0, 1]: the phase of the send time within the poll cycle
    (wait = u · cycle_s; ignored when cycle_s = 0); ``z_jitter``: a standard
    normal; ``reordered``: the frame is held back by ``reorder_delay_s``;
    ``latency_s`` / ``jitter_s``: per-run values replacing the parameters'
    (see :func:`propagation_delay_s`). Arguments broadcast like numpy arrays.
    :class:`SimChannel` uses exactly this model (plus queueing behind earlier frames).
    """
    u = np.asarray(u_cycle, dtype=np.float64)
    if np.any((u < 0.0) | (u > 1.0)) or not np.all(np.isfinite(u)):
        raise LinkError(f"u_cycle must lie in [0, 1] (got {u_cycle!r})")
    wait = u * params.cycle_s
    held = np.where(np.asarray(reordered, dtype=bool), params.reorder_delay_s, 0.0)
    prop = propagation_delay_s(params, z_jitter, latency_s=latency_s, jitter_s=jitter_s)
    total = wait + np.asarray(airtime_s(params, n_bytes)) + np.asarray(prop) + held
    return _out(np.asarray(total))


def mean_delivery_delay_s(params: ChannelParams, n_bytes: ArrayLike) -> float | FloatArray:
    """Mean of :func:`delivery_delay_s` over u ~ U[0, 1), z ~ N(0, 1) and reordering.

    cycle_s / 2 (mean wait for a slot) + airtime + mean propagation
    + reorder_probability · reorder_delay_s.
    """
    extra = 0.5 * params.cycle_s + mean_propagation_delay_s(params)
    extra += params.reorder_probability * params.reorder_delay_s
    return _out(np.asarray(airtime_s(params, n_bytes)) + extra)


def corruption_probability(
    params: ChannelParams, n_bytes: ArrayLike, *, bit_error_rate: ArrayLike | None = None
) -> float | FloatArray:
    """Probability that a delivered copy has at least one flipped bit: 1 − (1 − BER)^(8 n).

    ``bit_error_rate``, if given (scalar or per-run array), replaces the parameter's.
    """
    n = _n_bytes(n_bytes)
    ber = np.asarray(_override("bit_error_rate", bit_error_rate, params.bit_error_rate, hi=1.0))
    # -expm1(bits · log1p(-BER)) keeps precision for tiny BER; BER = 1 gives log1p(-1) = -inf.
    with np.errstate(divide="ignore", invalid="ignore"):
        p = -np.expm1(8.0 * n * np.log1p(-ber))
    p = np.where(n > 0, p, 0.0)  # no bits, nothing to corrupt (also avoids 0 · -inf)
    return _out(np.asarray(p))


def stationary_loss_probability(params: ChannelParams) -> float:
    """Long-run share of frames lost: 1 − (1 − p_loss)(1 − π_bad · p_loss_bad)."""
    burst = params.burst_bad_fraction * params.burst_loss_probability
    return 1.0 - (1.0 - params.loss_probability) * (1.0 - burst)


# --------------------------------------------------------------------------
# The event-by-event driver


@dataclass(frozen=True, slots=True)
class LinkStreams:
    """The counter-based stream keys of one link direction (module docstring: which draw is which).

    ``loss``, ``latency``, ``corrupt``: the stop model's radio streams of a run
    (:meth:`for_run`) or a link's own (:meth:`for_link`); ``faults`` and
    ``flips``: the draws the stop model has no use for (bursts, duplicates,
    reordering, further bit flips)."""

    loss: int
    latency: int
    corrupt: int
    faults: int
    flips: int

    def __post_init__(self) -> None:
        for name in ("loss", "latency", "corrupt", "faults", "flips"):
            v = getattr(self, name)
            if type(v) is not int or not 0 <= v < 2**64:
                raise LinkError(f"LinkStreams.{name}: a 64-bit key (got {v!r})")

    @classmethod
    def for_run(cls, seed: int, run: int) -> LinkStreams:
        """Run ``run``'s radio keys of the stop model (``model.step``: ``k_loss``, ``k_latency``,
        ``k_corrupt``), so that this medium draws what a campaign's run draws."""

        def key(stream: Stream) -> int:
            return py_stream_key(py_seed_key(seed, int(stream)), run)

        return cls(
            loss=key(Stream.RADIO_LOSS),
            latency=key(Stream.RADIO_LATENCY),
            corrupt=key(Stream.RADIO_CORRUPT),
            faults=key(Stream.LINK_FAULTS),
            flips=key(Stream.LINK_FLIPS),
        )

    @classmethod
    def for_link(cls, seed: int, owner: Stream, *identity: int) -> LinkStreams:
        """The keys of a link named by its owner stream and integers (e.g. ``Stream.DOOR_LINK``,
        train, dwell, direction): those of :meth:`for_run` for a "run" folded from them, with its
        top bit set, so that no link shares a campaign run's numbers (runs are below 2^63)."""
        return cls.for_run(seed, py_fold(int(owner), *(int(x) for x in identity)) | (1 << 63))


@dataclass(frozen=True, slots=True, kw_only=True)
class ChannelStats:
    """Counts of a :class:`SimChannel` so far.

    ``sent``: send() calls; ``sent_in_burst``: of those, sent in the bad state;
    ``lost``: frames that never arrive (``lost_in_outage`` of them in an
    outage); ``duplicated``: extra copies made; ``reordered``: frames held
    back; ``corrupted``: copies with at least one flipped bit; ``delivered``:
    copies returned by receive().
    """

    sent: int = 0
    sent_in_burst: int = 0
    lost: int = 0
    lost_in_outage: int = 0
    duplicated: int = 0
    reordered: int = 0
    corrupted: int = 0
    delivered: int = 0


def _outages(outages: object) -> tuple[tuple[float, float], ...]:
    try:
        spans = tuple((float(a), float(b)) for a, b in outages)  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        raise LinkError(f"outages: (start_s, end_s) pairs (got {outages!r})") from None
    for a, b in spans:
        if not (math.isfinite(a) and not math.isnan(b) and a <= b):
            raise LinkError(f"outage: needs a finite start_s <= end_s (inf: for good) (got {(a, b)!r})")
    return spans


class SimChannel:
    """One direction of a simulated medium: ``send(frame, now_s)``, ``receive(now_s)``.

    Pure unit (DESIGN rule 2): no clock, no socket; time is an argument and
    randomness comes from the link's counter-based streams (:class:`LinkStreams`;
    which draw is which: module docstring). Send times must not decrease.
    ``slot_phase_s``: the poll-cycle slots are at ``slot_phase_s + k · cycle_s``.
    ``outages``: (start_s, end_s) spans in which every frame sent is lost.
    """

    def __init__(
        self,
        params: ChannelParams,
        streams: LinkStreams,
        *,
        slot_phase_s: float = 0.0,
        outages: object = (),
    ) -> None:
        if not isinstance(params, ChannelParams):
            raise LinkError(f"params must be ChannelParams (got {type(params).__name__})")
        if not isinstance(streams, LinkStreams):
            raise LinkError(f"streams must be LinkStreams (got {type(streams).__name__})")
        if not math.isfinite(slot_phase_s):
            raise LinkError(f"slot_phase_s must be finite (got {slot_phase_s!r})")
        self.params = params
        self.streams = streams
        self.outages = _outages(outages)
        self._phase_s = float(slot_phase_s)
        self._frames = 0  # the counter of the next frame sent
        self._bad = False  # Gilbert–Elliott state; starts good
        self._last_send_s = -math.inf
        self._medium_free_s = -math.inf  # end of the last transmission
        self._last_slot: int | None = None  # index of the last slot used
        self._in_order_s = -math.inf  # arrival of the last frame not held back (FIFO floor)
        self._queue: list[tuple[float, int, bytes]] = []  # (arrival_s, insertion no., frame)
        self._seq = 0
        self._counts = dict.fromkeys(ChannelStats.__dataclass_fields__, 0)
        ber = params.bit_error_rate
        self._log_keep = math.log1p(-ber) if 0.0 < ber < 1.0 else 0.0  # log(1 − BER) per bit
        self._p_any: dict[int, float] = {}

    @property
    def stats(self) -> ChannelStats:
        return ChannelStats(**self._counts)

    def _departure_s(self, now_s: float) -> float:
        """When the frame starts on the medium: free medium, next free cycle slot (SPEC §5)."""
        start = max(now_s, self._medium_free_s)
        cycle = self.params.cycle_s
        if cycle == 0.0:
            return start
        x = (start - self._phase_s) / cycle
        k = math.ceil(x - _SLOT_EPS)
        if self._last_slot is not None:
            k = max(k, self._last_slot + 1)  # one frame per slot
        self._last_slot = k
        return self._phase_s + k * cycle

    def _flips(self, nbits: int, c: int, copy: int) -> list[int]:
        """The flipped bit positions of frame ``c``'s copy ``copy`` (none, mostly): every bit
        flips independently with the bit error rate (module docstring: the draws)."""
        ber = self.params.bit_error_rate
        if ber == 0.0 or nbits == 0:
            return []
        if ber >= 1.0:
            return list(range(nbits))
        p_any = self._p_any.get(nbits)
        if p_any is None:  # P(at least one flip) of a frame this long, once per length
            p_any = self._p_any[nbits] = float(corruption_probability(self.params, nbits // 8))
        if copy == 0:  # the stop model's draws: corrupted? and where the first flip is
            if not py_key_uniform(self.streams.corrupt, 2 * c) < p_any:
                return []
            u_first = py_key_uniform(self.streams.corrupt, 2 * c + 1)
        sub = py_stream_key(self.streams.flips, 2 * c + copy)  # the copy's own key: further flips
        if copy != 0:
            if not py_key_uniform(sub, 0) < p_any:
                return []
            u_first = py_key_uniform(sub, 1)
        # Given a flip, P(first flip <= j) = (1 − (1 − BER)^(j+1)) / p_any: inverted.
        first = math.ceil(math.log1p(-u_first * p_any) / self._log_keep) - 1
        pos = [min(max(first, 0), nbits - 1)]
        j = 2
        while True:  # geometric gaps: the next bit that flips after the last one
            u = py_key_uniform(sub, j)
            j += 1
            gap = max(1, math.ceil(math.log1p(-u) / self._log_keep)) if u > 0.0 else 1
            nxt = pos[-1] + gap
            if nxt >= nbits:
                return pos
            pos.append(nxt)

    def _corrupt(self, frame: bytes, c: int, copy: int) -> bytes:
        pos = self._flips(8 * len(frame), c, copy)
        if not pos:
            return frame
        buf = bytearray(frame)
        for b in pos:
            buf[b >> 3] ^= 0x80 >> (b & 7)
        self._counts["corrupted"] += 1
        return bytes(buf)

    def _push(self, arrival_s: float, frame: bytes) -> None:
        heapq.heappush(self._queue, (arrival_s, self._seq, frame))
        self._seq += 1

    def send(self, frame: bytes, now_s: float) -> float | None:
        """Hand a frame to the medium at ``now_s`` (seconds; not earlier than the previous send):
        when it will arrive (its first copy), None when it is lost."""
        if type(frame) is not bytes:  # (a bytes object is taken as it is)
            if not isinstance(frame, bytes | bytearray | memoryview):
                raise LinkError(f"frame must be bytes (got {type(frame).__name__})")
            frame = bytes(frame)
        now_s = float(now_s)
        if not math.isfinite(now_s):
            raise LinkError(f"now_s must be finite (got {now_s!r})")
        if now_s < self._last_send_s:
            raise LinkError(f"now_s went backwards: {now_s!r} after a send at {self._last_send_s!r}")
        self._last_send_s = now_s
        p, ks = self.params, self.streams
        c = self._frames  # this frame's counter in every stream
        self._frames = c + 1
        self._counts["sent"] += 1
        if self.outages and any(a <= now_s < b for a, b in self.outages):
            self._counts["lost"] += 1  # the radio is dead: nothing goes out
            self._counts["lost_in_outage"] += 1
            return None

        # Gilbert–Elliott: advance the chain once per frame, then judge this frame. (A good chain
        # that cannot enter the bad state stays good: its draw, counter-based, is not needed.)
        if self._bad or p.burst_enter_probability > 0.0:
            u_state = py_key_uniform(ks.faults, 4 * c)
            self._bad = (
                (u_state >= p.burst_exit_probability) if self._bad else (u_state < p.burst_enter_probability)
            )
            self._counts["sent_in_burst"] += int(self._bad)

        depart_s = self._departure_s(now_s)
        air_s = float(airtime_s(p, len(frame)))
        duplicated = (
            p.duplicate_probability > 0.0 and py_key_uniform(ks.faults, 4 * c + 2) < p.duplicate_probability
        )
        # The medium is busy during the transmission (twice for a duplicate), lost or not.
        self._medium_free_s = depart_s + air_s * (2 if duplicated else 1)

        lost = py_key_uniform(ks.loss, c) < p.loss_probability or (
            self._bad and py_key_uniform(ks.faults, 4 * c + 1) < p.burst_loss_probability
        )
        if lost:
            self._counts["lost"] += 1
            return None

        reordered = (
            p.reorder_probability > 0.0 and py_key_uniform(ks.faults, 4 * c + 3) < p.reorder_probability
        )
        # Same model as delivery_delay_s() (and the stop model's attempt): airtime + propagation
        # (+ hold-back).
        z = py_key_normal(ks.latency, c) if p.jitter_s > 0.0 else 0.0
        arrival_s = depart_s + (air_s + float(propagation_delay_s(p, z)))
        if reordered:
            arrival_s += p.reorder_delay_s
            self._counts["reordered"] += 1
        else:
            # FIFO: jitter never lets a frame overtake an earlier one.
            arrival_s = max(arrival_s, self._in_order_s)
            self._in_order_s = arrival_s
        self._push(arrival_s, self._corrupt(frame, c, 0))
        if duplicated:
            self._counts["duplicated"] += 1
            self._push(arrival_s + air_s, self._corrupt(frame, c, 1))
            if not reordered:
                self._in_order_s = arrival_s + air_s  # later frames do not overtake the copy
        return arrival_s

    def receive(self, now_s: float) -> list[bytes]:
        """Frames that have arrived by ``now_s``, in arrival order; each is returned once."""
        out: list[bytes] = []
        while self._queue and self._queue[0][0] <= now_s:
            out.append(heapq.heappop(self._queue)[2])
        self._counts["delivered"] += len(out)
        return out

    def next_arrival_s(self) -> float | None:
        """Arrival time of the next frame in flight, or None."""
        return self._queue[0][0] if self._queue else None

    def in_flight(self) -> int:
        """Copies sent but not yet received."""
        return len(self._queue)


def media_preset(name: str, path: str | Path | None = None) -> ChannelParams:
    """One medium by name (``loop``, ``transponder``, ``radio``) from the embedded presets or ``path``."""
    media = load_media(path)
    if name not in media:
        source = f"railstop/data/{MEDIA_FILE}" if path is None else str(path)
        raise ConfigError(source, "(medium)", f"unknown medium; available: {', '.join(sorted(media))}", name)
    return media[name]


__all__ = [
    "ChannelStats",
    "LinkError",
    "LinkStreams",
    "SimChannel",
    "airtime_s",
    "corruption_probability",
    "delivery_delay_s",
    "mean_delivery_delay_s",
    "mean_propagation_delay_s",
    "media_preset",
    "propagation_delay_s",
    "stationary_loss_probability",
]
