"""The line under SPEC §4 moving-block CBTC: the zone controller, the trains' onboard units, the radio.

``LineSimulation(signalling="cbtc" | "cbtc-conventional")`` builds one
:class:`CbtcSignalling`: a :class:`~railstop.wayside.zone_controller.ZoneController`
("zc"), one :class:`~railstop.onboard.cbtc.OnboardCbtc` per train
("cbtc-k") and the :class:`~railstop.link.cbtc_radio.CbtcRadio` ("radio")
between them, all units of the line's clock. Each plant step the driver
tells every active onboard unit where its train believes it is (the SPEC §2
onboard position) and reads back what the train may do: its authority's end
and whether its emergency brake is on.

It also counts, against the true positions, what must never happen:
**authority overlaps** (an authority end granted beyond the true rear of the
train ahead, or into another train's protection zone, at the moment it is
granted) and **collisions** (a front past the true rear of the train ahead).
Every zone the controller sets is recorded (train, extent, set and release
times) for the time-distance diagram.

A train whose radio is dead (an outage of the faults) is moved by its driver in
**restricted mode** (``onboard.restricted_mode``, the rule live operation's
trains follow): after its emergency brake and a wait, on sight at 15 km/h for
up to 400 m; one driver per train here (``CbtcSignalling.restricted``, asked by
the line's plant step with :meth:`CbtcSignalling.radio_dead`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from railstop.config.media import ChannelParams
from railstop.config.schema import Line, Vehicle
from railstop.link.cbtc_radio import CbtcRadio
from railstop.link.release_link import OperatorConsole, ReleaseGate
from railstop.messages import Message, MovementCommand, OnboardPosition, Output
from railstop.nodes.train import make_onboard_cbtc
from railstop.nodes.zone import make_zone_controller
from railstop.onboard.cbtc import OnboardCbtc
from railstop.onboard.restricted_mode import RestrictedMode
from railstop.units import Unit
from railstop.wayside.zone_controller import TrainStatus, ZoneController, ZoneMode

SIGNALLING_MODES = ("fixed-block", "cbtc", "cbtc-conventional")


@dataclass(frozen=True, slots=True, kw_only=True)
class ZoneRecord:
    train: int
    start_m: float
    end_m: float
    set_s: float
    released_s: float  # inf: still set at the end of the run


class _CheckedZc:
    """The zone controller as the clock sees it, with every command it grants checked against
    the true world (the driver's bookkeeping; the controller itself is untouched)."""

    accepts: tuple[type, ...]

    def __init__(self, zc: ZoneController, owner: CbtcSignalling) -> None:
        self.zc = zc
        self.name = zc.name
        self.accepts = zc.accepts
        self.owner = owner

    def handle(self, message: Message, now_s: float) -> list[Output]:
        before = self._zones()
        outs = self.zc.handle(message, now_s)
        self._note(before, now_s)
        return outs

    def next_deadline_s(self) -> float | None:
        return self.zc.next_deadline_s()

    def _zones(self) -> dict[int, object]:
        return {t.train_id: t.zone for t in self.zc.trains.values()}

    def _note(self, before: dict[int, object], now_s: float) -> None:
        for t in self.zc.trains.values():
            if t.zone is not None and before.get(t.train_id) is None:
                self.owner.zone_set(t.train_id, t.zone.start_m, t.zone.end_m, now_s)

    def on_timer(self, now_s: float) -> list[Output]:
        before = self._zones()
        outs = self.zc.on_timer(now_s)
        self._note(before, now_s)
        for o in outs:
            if isinstance(o.message, MovementCommand):
                self.owner.check_grant(o.message, now_s)
        return outs


@dataclass(slots=True)
class CbtcSignalling:
    line: Line
    vehicle: Vehicle
    mode: ZoneMode
    trains: int
    radio_params: ChannelParams
    seed: int
    outages: dict[int, list[tuple[float, float]]] = field(default_factory=dict)
    zc: ZoneController = field(init=False)
    radio: CbtcRadio = field(init=False)
    onboard: list[OnboardCbtc] = field(init=False)
    restricted: list[RestrictedMode] = field(init=False)  # each train's driver, radio dead
    active: list[bool] = field(init=False)
    true_front: list[float] = field(init=False)
    on_line: list[bool] = field(init=False)
    authority_overlaps: int = 0
    collisions: int = 0
    uncertainty_exceeded: int = 0  # steps with a train's true front outside its reported bound
    uncertainty_margin_min_m: float = math.inf  # the least (bound - |onboard - true|) on the line
    uncertainty_max_m: float = 0.0  # the largest bound a train on the line reported
    zones: list[ZoneRecord] = field(default_factory=list)
    _open_zones: dict[int, tuple[float, float, float]] = field(default_factory=dict)
    _checked: _CheckedZc = field(init=False)
    _end_s: float = 0.0
    console: OperatorConsole = field(default_factory=OperatorConsole)
    gate: ReleaseGate = field(default_factory=ReleaseGate)
    _flagged_at: dict[int, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.zc = make_zone_controller(self.line, self.vehicle, self.mode)
        self.radio = CbtcRadio(params=self.radio_params, seed=self.seed, outages=self.outages)
        self.onboard = [
            make_onboard_cbtc(self.line, self.vehicle, k, uplink=self.radio.name) for k in range(self.trains)
        ]
        brake = self.vehicle.brake.full_service_mps2
        self.restricted = [RestrictedMode(brake_mps2=brake) for _ in range(self.trains)]
        self.active = [False] * self.trains
        self.true_front = [math.nan] * self.trains
        self.on_line = [False] * self.trains
        self.zc.downlink = self.radio.name
        self._checked = _CheckedZc(self.zc, self)

    def units(self) -> list[Unit]:
        return [self._checked, self.radio, *self.onboard]

    # ------------------------------------------------------------------ the driver's side

    def observe(
        self,
        k: int,
        *,
        onboard_m: float,
        speed_mps: float,
        true_m: float,
        on_line: bool,
        uncertainty_m: float | None = None,
    ) -> list[Output]:
        """The train's true position for the checks, and its onboard position for its unit (once
        active; delivered by the clock, which then knows the unit's next report) with its location
        uncertainty: ``uncertainty_m`` (the line: its positioning unit's), or where the driver
        gives none the declared bound (``[cbtc] position_uncertainty_m``, [interpretation])."""
        self.true_front[k] = true_m
        self.on_line[k] = on_line
        if not self.active[k]:
            return []
        u = self.line.cbtc.position_uncertainty_m if uncertainty_m is None else uncertainty_m
        if on_line:
            margin = u - abs(onboard_m - true_m)
            if margin < 0.0:
                self.uncertainty_exceeded += 1  # the bound the train reports does not hold
            self.uncertainty_margin_min_m = min(self.uncertainty_margin_min_m, margin)
            self.uncertainty_max_m = max(self.uncertainty_max_m, u)
        position = OnboardPosition(position_m=onboard_m, speed_mps=speed_mps, uncertainty_m=u)
        return [Output(to=self.onboard[k].name, message=position)]

    def activate(self, k: int) -> None:
        """The train's onboard unit starts (it is next to enter the line): from the next step on
        it gets its position, and its first report goes out with the first."""
        self.active[k] = True

    def authority_end_m(self, k: int) -> float:
        """Where the train's ATO may aim, on its own chainage (-inf: no authority): the end of
        its authority less ``ato_stop_short_m`` (IEEE 1474.1: the ATO runs under the emergency brake
        intervention curve, which near the end keeps the reaction distance) and less what its
        location uncertainty has grown since the report the authority answers."""
        unit = self.onboard[k]
        if math.isnan(unit.authority_end_m) or math.isnan(unit.position_m):
            return -math.inf
        room = unit.distance_to_end_m() - self.line.cbtc.ato_stop_short_m
        return unit.position_m + unit.sign * room

    def emergency_brake(self, k: int) -> bool:
        return self.onboard[k].emergency_brake

    def radio_dead(self, k: int, now_s: float) -> bool:
        """Whether train ``k``'s radio is dead now: an outage of the faults, which its driver knows
        of (no network in the cab, as live operation's dead radios); the medium's losses and bursts
        are not (the train's unit brakes on them, its driver waits for the next command)."""
        return any(a <= now_s < b for a, b in self.outages.get(k, ()))

    def check_collisions(self) -> None:
        fronts = sorted((self.true_front[k], k) for k in range(self.trains) if self.on_line[k])
        length = self.vehicle.length_m
        for (f1, _), (f2, _) in zip(fronts, fronts[1:], strict=False):
            if f1 > f2 - length:
                self.collisions += 1

    # ------------------------------------------------------------------ the checks

    def check_grant(self, cmd: MovementCommand, now_s: float) -> None:
        """An authority end granted beyond the true rear of the train ahead, or into another
        train's zone, is an overlap (counted: it must not happen)."""
        k = cmd.train_id
        t = self.zc.trains.get(k)
        if t is None or t.report is None or cmd.authority_m <= 0.0:
            return
        end = t.granted_end_m
        me = self.true_front[k]
        length = self.vehicle.length_m
        for j in range(self.trains):
            if j == k or not self.on_line[j]:
                continue
            rear = self.true_front[j] - length
            if self.true_front[j] > me and end > rear:
                self.authority_overlaps += 1
                return
        for z in self.zc.zones():
            if z.train_id != k and z.start_m > me and end > z.start_m:
                self.authority_overlaps += 1
                return

    def zone_set(self, train: int, start_m: float, end_m: float, now_s: float) -> None:
        self._open_zones[train] = (start_m, end_m, now_s)

    def operator(self, now_s: float) -> list[Output]:
        """SPEC §4 step 5: the operator releases a flagged train ``operator_release_s`` after it
        was flagged, through the authenticated release link."""
        out: list[Output] = []
        for k, t in self.zc.trains.items():
            if t.status != TrainStatus.FLAGGED:
                self._flagged_at.pop(k, None)
                continue
            since = self._flagged_at.setdefault(k, now_s)
            if now_s - since >= self.line.cbtc.operator_release_s:
                release = self.gate.accept(self.console.release(k, now_s), now_s)
                if release is not None:
                    out.append(Output(to=self.zc.name, message=release))
                self._flagged_at[k] = now_s  # not again at once, whatever came of it
        return out

    def sweep_zones(self, now_s: float) -> None:
        """Close the records of zones the controller has released."""
        live = {z.train_id for z in self.zc.zones()}
        for train in [t for t in self._open_zones if t not in live]:
            a, b, t0 = self._open_zones.pop(train)
            self.zones.append(ZoneRecord(train=train, start_m=a, end_m=b, set_s=t0, released_s=now_s))

    def finish(self, now_s: float) -> None:
        self.sweep_zones(now_s)
        for train, (a, b, t0) in self._open_zones.items():
            self.zones.append(ZoneRecord(train=train, start_m=a, end_m=b, set_s=t0, released_s=math.inf))
        self._open_zones.clear()
        self._end_s = now_s

    def summary(self) -> dict[str, Any]:
        c = self.zc.counts
        r = self.radio.counts
        return {
            "mode": self.mode.value,
            "reports": c.reports,
            "commands": c.commands,
            "lost_trains": c.lost,
            "auto_releases": c.auto_releases,
            "flagged": c.flagged,
            "manual_releases": c.manual_releases,
            "restarts": c.restarts,
            "releases_refused": int(sum(self.gate.rejected.values())),
            "authority_overlaps": self.authority_overlaps,
            "collisions": self.collisions,
            "uncertainty_exceeded": self.uncertainty_exceeded,
            "uncertainty_margin_min_m": _finite_or_none(self.uncertainty_margin_min_m, 3),
            "uncertainty_max_m": round(self.uncertainty_max_m, 3),
            "onboard_emergency_brakes": int(sum(u.eb_count for u in self.onboard)),
            # By the causes' labels, in their order (EbCause: the JSON keys stay the printed names).
            "onboard_eb_causes": {
                cause.label: sum(u.eb_causes.get(cause, 0) for u in self.onboard)
                for cause in sorted({c for u in self.onboard for c in u.eb_causes}, key=lambda c: c.label)
            },
            # Restricted mode (radio dead): the movements its drivers began, the distance they ran.
            "restricted_moves": int(sum(d.moves for d in self.restricted)),
            "restricted_m": round(sum(d.run_m for d in self.restricted), 1),
            "radio_lost": r.lost,
            "radio_rejected": int(sum(r.rejected.values())),
            "zones": len(self.zones),
            # Zone-seconds: how long zones stood, summed (a zone still set counts to the run's end).
            "zone_time_s": round(sum(min(z.released_s, self._end_s) - z.set_s for z in self.zones), 1),
            # The line capacity the zones took: protected length x time (metre-seconds).
            "zone_m_s": round(
                sum((z.end_m - z.start_m) * (min(z.released_s, self._end_s) - z.set_s) for z in self.zones), 1
            ),
        }


def outage_windows(items: Sequence[tuple[int, float, float]]) -> dict[int, list[tuple[float, float]]]:
    out: dict[int, list[tuple[float, float]]] = {}
    for train, start, duration in items:
        out.setdefault(train, []).append((start, start + duration))
    return out


def _finite_or_none(value: float, digits: int) -> float | None:
    """A figure for the JSON summary: rounded, or None where no train was ever on the line."""
    return round(value, digits) if math.isfinite(value) else None
