"""Line layout data for the line with many trains: segments, block signalling, speed limits.

- **Segments** with IDs are what the CBTC zone controller protects (SPEC §4:
  a protection zone covers every segment from a lost train's occupancy end to
  its forward stop point). They cover the line from chainage 0, contiguous.
- **Blocks** are the fixed-block signalling of the line before CBTC: each is
  a run of consecutive track circuits (SPEC §2's circuits, so the block's
  occupancy is the circuits' occupancy) with a signal at its entry. A train
  may run into a block only when the signal at its entry shows proceed, i.e.
  the block and the overlap beyond its end are clear (``blocks_ahead`` = 1;
  more blocks for a more restrictive layout). **[interpretation]**
  the source documents describe CBTC and the stop; the fixed block is the
  conventional baseline the line simulation needs until CBTC replaces it.
- **Speed limits** are civil limits over a stretch (curves, turnouts); the
  line's own limit applies elsewhere, and the lower of the two where both do.

Every rule here is a check on data a railway engineer edits (DESIGN rule 6):
a problem names the field and its value (``FieldProblem``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Protocol

from pydantic import Field

from railstop.config.base import FieldProblem, Model, Stretch


class Segment(Stretch):
    """A track segment with an ID (SPEC §4: the zone controller's unit of protection)."""

    id: Annotated[int, Field(ge=1, le=65535)]  # 16 bits, as in the CBTC telegrams


class Block(Model):
    """A fixed block: consecutive track circuits (listed in running order) and its entry signal."""

    # The block's name, unique on the line (the checks' messages name it).
    id: Annotated[str, Field(min_length=1, max_length=16)]
    # The track circuits of the block by ID, in running order: consecutive circuits of the line, each
    # circuit in exactly one block; its occupancy is theirs.
    circuits: list[Annotated[int, Field(ge=1, le=65535)]] = Field(min_length=1)
    # The name of the signal at the block's entry (unique): it stands at the start of the block's
    # first circuit and shows proceed only when the block and the overlap are clear.
    signal: Annotated[str, Field(min_length=1, max_length=16)]


class Signalling(Model):
    """Fixed-block signalling: the blocks in running order and the safety distances."""

    # The blocks in running order; together they take every track circuit of the line once.
    blocks: list[Block] = Field(min_length=1)
    # The overlap: the stretch beyond a red signal that must be clear as well, for a train
    # that stops a little past it (a common 50-200 m; this line runs ATP to the signal).
    overlap_m: Annotated[float, Field(ge=0.0, le=500.0, allow_inf_nan=False)] = 50.0
    # How many blocks from its own must be clear (with the overlap beyond the last) for a signal
    # to show proceed: 1, the usual rule (the next signal may be at stop: a caution aspect);
    # more is a more restrictive layout.
    blocks_ahead: Annotated[int, Field(ge=1, le=5)] = 1


class Cbtc(Model):
    """SPEC §4 moving-block CBTC: the cycles, the counts and the distances of the zone controller."""

    # SPEC §4: reports and commands run on fixed cycles; the paper gives none, a CBTC heartbeat
    # is typically 0.5-1 s.
    report_period_s: Annotated[float, Field(gt=0.0, le=5.0, allow_inf_nan=False)] = 0.5
    # SPEC §4 Δt: from receiving report a0 to generating command b0 (assumption: 0.2 s).
    processing_delay_s: Annotated[float, Field(ge=0.0, le=5.0, allow_inf_nan=False)] = 0.2
    # SPEC §4: position compensation Pc = Pp ± Δt·Vp (false: commands from Pp, for comparison).
    compensate: bool = True
    # SPEC §4: 2 or more consecutive missed reports -> the train is lost (its zone is set).
    missed_reports_lost: Annotated[int, Field(ge=1, le=20)] = 2
    # SPEC §4: 2 or more consecutive missed commands -> the onboard unit's emergency brake.
    missed_commands_eb: Annotated[int, Field(ge=1, le=20)] = 2
    # The authority ends this far behind the rear of the train ahead or a protection zone
    # (assumption: the braking-curve uncertainty and the radio's uncompensated latency).
    safety_margin_m: Annotated[float, Field(ge=0.0, le=1000.0, allow_inf_nan=False)] = 20.0
    # IEEE 1474.1 rollback allowance: a train ahead may roll back this far before its own
    # protection stops it; the authority behind it ends this much earlier, its zone starts so much
    # further back (assumption: 2 m, a metro's rollback protection).
    rollback_m: Annotated[float, Field(ge=0.0, le=50.0, allow_inf_nan=False)] = 2.0
    # The location uncertainty reported where no positioning unit gives one (the live trains,
    # whose position is the plant's; the zone model of `zones verify`): the true front lies within
    # ± this of the reported position ([interpretation]: the SPEC §2 chain's worst error on this
    # line is about 7 m, docs/position.md; 8 m bounds it).
    position_uncertainty_m: Annotated[float, Field(ge=0.0, le=1000.0, allow_inf_nan=False)] = 8.0
    # On the line, each train reports its positioning unit's own uncertainty (IEEE 1474.1: from
    # the positioning's confidence): this many standard deviations of its dead reckoning since
    # the last fix, plus the bound of the slides it could not bridge ([interpretation]: the
    # standard asks for a bound held at the system's safety level and gives no number; 5 standard
    # deviations of a normal error leave 6e-7 outside. The line counts every step at which a
    # train's true front lay outside: `uncertainty_exceeded`).
    position_confidence_sigmas: Annotated[float, Field(ge=1.0, le=10.0, allow_inf_nan=False)] = 5.0

    # IEEE 1474.1 safe braking model of the onboard overspeed supervision: from the moment the
    # train is over the curve, the supervision takes ``overspeed_detection_s`` to see it and the
    # propulsion ``propulsion_cutoff_s`` to be cut (the train accelerating at
    # ``runaway_accel_mps2`` all that time, plus a downhill gradient), the emergency brake
    # ``brake_build_up_s`` to build up (coasting), then the train stops at the guaranteed
    # emergency brake rate ``gebr_mps2`` (flat track; less a downhill gradient). SPEC "typical
    # values": emergency about 1.3 m/s², brake dead time 0.2-0.6 s and build-up 0.3-0.6 s (1.2 s:
    # the worst dead time plus one build-up time constant, the lag's lost time). Bounds: no
    # negative time or acceleration; no guaranteed brake or runaway above 3 m/s² (about 0.3 g,
    # more than wheel on rail can give).
    gebr_mps2: Annotated[float, Field(gt=0.0, le=3.0, allow_inf_nan=False)] = 1.1
    # Safe braking model: the supervision's time to see the overspeed (the train accelerating at
    # runaway_accel_mps2).
    overspeed_detection_s: Annotated[float, Field(ge=0.0, le=5.0, allow_inf_nan=False)] = 0.2
    # Safe braking model: after the detection, the time to cut the propulsion (the train still
    # accelerating at runaway_accel_mps2).
    propulsion_cutoff_s: Annotated[float, Field(ge=0.0, le=5.0, allow_inf_nan=False)] = 0.5
    # Safe braking model: after the cut-off, the emergency brake's build-up time (the train coasting;
    # downhill, accelerating).
    brake_build_up_s: Annotated[float, Field(ge=0.0, le=10.0, allow_inf_nan=False)] = 1.2
    # Safe braking model: the train's acceleration while the overspeed is detected and the
    # propulsion cut (plus a downhill gradient).
    runaway_accel_mps2: Annotated[float, Field(ge=0.0, le=3.0, allow_inf_nan=False)] = 1.0
    # The line's ATO aims this far short of the authority's end: the intervention curve keeps its
    # reaction distance (about 1.3 m at a standstill, 4.7 m more than the ATO's 0.7 m/s² approach
    # near 3.6 m/s with the default values), which an approach to the end itself would cross.
    ato_stop_short_m: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)] = 8.0

    # SPEC §4 step 5: a train re-detected outside its zone waits for the operator's release after
    # visual confirmation; in the line simulation the operator releases it this long after it
    # was flagged (assumption: staff reach the train and confirm).
    operator_release_s: Annotated[float, Field(gt=0.0, le=3600.0, allow_inf_nan=False)] = 180.0


class SpeedLimit(Stretch):
    """A civil speed limit over a stretch of the line."""

    # The civil limit over the stretch; where the line's own limit is lower, the lower one holds.
    limit_kmh: Annotated[float, Field(gt=0.0, le=200.0, allow_inf_nan=False)]
    # Why the limit is there (a curve, a turnout); for the reader, the simulation does not use it.
    reason: Annotated[str, Field(max_length=64)] | None = None


class _IdStretch(Protocol):
    id: int
    start_m: float
    end_m: float


def check_chain(items: Sequence[_IdStretch], field: str, noun: str, short: str) -> None:
    """IDs unique; in order and contiguous from chainage 0 (``field`` names the list in messages,
    ``noun`` its items, ``short`` one item before its ID)."""
    seen: dict[int, int] = {}
    for i, s in enumerate(items):
        if s.id in seen:
            raise FieldProblem(
                f"{field}[{i}].id", f"{noun} IDs must be unique: {s.id} is also {field}[{seen[s.id]}]"
            )
        seen[s.id] = i
    if items and items[0].start_m != 0.0:
        raise FieldProblem(
            f"{field}[0].start_m", f"the first {noun} must start at chainage 0, got {items[0].start_m}"
        )
    for i in range(1, len(items)):
        prev, cur = items[i - 1], items[i]
        if cur.start_m != prev.end_m:
            what = "overlaps" if cur.start_m < prev.end_m else "leaves a gap after"
            raise FieldProblem(
                f"{field}[{i}].start_m",
                f"{noun}s must be listed in order and contiguous: {short} {cur.id} starts at "
                f"{cur.start_m} m and {what} {short} {prev.id} ending at {prev.end_m} m",
            )


def check_segments(segments: Sequence[Segment], line_end_m: float | None) -> None:
    """Unique IDs, in order and contiguous from chainage 0 to the line's end."""
    check_chain(segments, "segments", "segment", "segment")
    if segments and line_end_m is not None and segments[-1].end_m != line_end_m:
        raise FieldProblem(
            f"segments[{len(segments) - 1}].end_m",
            f"the last segment must end at the line's end ({line_end_m} m), got {segments[-1].end_m}",
        )


def check_blocks(blocks: Sequence[Block], circuit_ids: Sequence[int]) -> None:
    """Every track circuit in exactly one block; blocks in running order, each a run of
    consecutive circuits; unique block IDs and signal names."""
    if not circuit_ids:
        raise FieldProblem("signalling.blocks", "blocks are made of track circuits: the line has none")
    order = {cid: k for k, cid in enumerate(circuit_ids)}
    ids: dict[str, int] = {}
    signals: dict[str, int] = {}
    expected = 0  # the index of the next circuit in running order
    for i, b in enumerate(blocks):
        if b.id in ids:
            raise FieldProblem(
                f"signalling.blocks[{i}].id",
                f"block IDs must be unique: {b.id!r} is also blocks[{ids[b.id]}]",
            )
        ids[b.id] = i
        if b.signal in signals:
            raise FieldProblem(
                f"signalling.blocks[{i}].signal",
                f"signal names must be unique: {b.signal!r} also stands at blocks[{signals[b.signal]}]",
            )
        signals[b.signal] = i
        for j, cid in enumerate(b.circuits):
            if cid not in order:
                raise FieldProblem(
                    f"signalling.blocks[{i}].circuits[{j}]", f"no track circuit {cid} on this line"
                )
            if order[cid] != expected:
                raise FieldProblem(
                    f"signalling.blocks[{i}].circuits[{j}]",
                    f"blocks must take the track circuits in running order, each once: circuit {cid} "
                    f"where circuit {circuit_ids[expected] if expected < len(circuit_ids) else '(none)'} "
                    "comes next",
                )
            expected += 1
    if expected != len(circuit_ids):
        raise FieldProblem(
            "signalling.blocks",
            f"the blocks must cover every track circuit: {circuit_ids[expected]} and after are in none",
        )


def check_speed_limits(limits: Sequence[SpeedLimit], line_end_m: float | None) -> None:
    """On the line and not overlapping (where a local limit is above the line's own, the lower
    one holds)."""
    ordered = sorted(enumerate(limits), key=lambda it: it[1].start_m)
    for (_, a), (j, b) in zip(ordered, ordered[1:], strict=False):
        if b.start_m < a.end_m:
            raise FieldProblem(
                f"speed_limits[{j}].start_m",
                f"speed limits overlap: {b.start_m} m is before the end of another at {a.end_m} m",
            )
    for i, s in enumerate(limits):
        if s.start_m < 0.0 or (line_end_m is not None and s.end_m > line_end_m):
            raise FieldProblem(f"speed_limits[{i}]", f"{s.start_m} .. {s.end_m} m is not on the line")


__all__ = [
    "Block",
    "Segment",
    "Signalling",
    "SpeedLimit",
    "check_blocks",
    "check_chain",
    "check_segments",
    "check_speed_limits",
]
