"""The CBTC zone controller (SPEC §4) under random fault sequences on a longer line.

A hypothesis state machine drives the real :class:`ZoneController` and one real
:class:`OnboardCbtc` per train through ``railstop.verify.zones.World``:
trains report (after advancing anywhere within the authority they hold, not
on a grid), lose reports (so that they get lost and braked), move while lost,
are released by the operator; time advances cycle by cycle. After every step
the invariants of ``zones_verify`` (the exhaustive search's) hold for every
cycle completed since. Here with a safety margin and a processing delay Δt > 0.
"""

from __future__ import annotations

from hypothesis import settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, precondition, rule

from railstop.config.layout import Cbtc
from railstop.verify.zones import INVARIANTS, Snapshot, Step, TrainAction, World, ZoneModel, initial_world
from railstop.wayside.zone_controller import TrainStatus, ZoneMode

TRAINS = 4
# 2.4 km of 150 m segments, blocks of 450 m; trains of 120 m; a 0.5 s cycle (SPEC §4: a CBTC
# heartbeat of 0.5-1 s), Δt = 0.2 s, a margin of 20 m.
LINE = ZoneModel(
    trains=TRAINS,
    segments=16,
    segment_m=150.0,
    segments_per_block=3,
    overlap_m=50.0,
    train_length_m=120.0,
    step_m=150.0,
    max_losses=1_000,  # unbounded here: a train may stay silent as long as the rules say
    params=Cbtc(
        report_period_s=0.5,
        processing_delay_s=0.2,
        missed_reports_lost=2,
        missed_commands_eb=2,
        safety_margin_m=20.0,
    ),
)

train_ids = st.integers(min_value=1, max_value=TRAINS)
fractions = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)


class ZoneControllerMachine(RuleBasedStateMachine):
    world: World
    before: Snapshot
    unchecked: list[tuple[Snapshot, Step, Snapshot]]

    @initialize(
        mode=st.sampled_from(list(ZoneMode)),
        gaps=st.lists(
            st.floats(min_value=LINE.train_length_m + 1.0, max_value=500.0, allow_nan=False),
            min_size=TRAINS - 1,
            max_size=TRAINS - 1,
        ),
    )
    def start(self, mode: ZoneMode, gaps: list[float]) -> None:
        fronts = [LINE.train_length_m + 10.0]
        for g in gaps:
            fronts.append(fronts[-1] + g)
        self.world = initial_world(LINE, mode, fronts=fronts)
        self.before = self.world.snapshot()
        self.unchecked = []
        self.cycles = 0
        self.seen: set[str] = set()

    # ------------------------------------------------------------------ helpers

    def _close(self) -> None:
        step = self.world.close()
        after = self.world.snapshot()
        self.unchecked.append((self.before, step, after))
        self.before = after
        self.cycles += 1
        for s in after.trains:
            self.seen.add(s.status.value)

    def _turn(self, train: int, to_m: float, deliver: bool, moved_while_lost: bool = False) -> None:
        self.world.turn(
            TrainAction(train=train, to_m=to_m, deliver=deliver, moved_while_lost=moved_while_lost)
        )

    def _fresh(self, train: int) -> None:
        """The train has had its turn this cycle: the cycle ends first."""
        if self.world.has_turned(train):
            self._close()

    def _advance(self, train: int, fraction: float) -> float:
        # A train obeys its authority and its brake (SPEC §4): anywhere up to what it may reach,
        # at most one segment a cycle.
        x = self.world.fronts[train - 1]
        reach = min(self.world.reach_m(train), x + LINE.step_m)
        return x + fraction * max(reach - x, 0.0)

    # ------------------------------------------------------------------ rules

    @rule(train=train_ids, fraction=fractions)
    def report(self, train: int, fraction: float) -> None:
        self._fresh(train)
        self._turn(train, self._advance(train, fraction), deliver=True)

    @rule(train=train_ids, cycles=st.integers(min_value=1, max_value=3), fraction=fractions)
    def lose_reports(self, train: int, cycles: int, fraction: float) -> None:
        # SPEC §4: the train's reports do not reach the controller (nor are they answered) for
        # ``cycles`` cycles in a row; time advances with them (2 or more: the train is lost).
        for _ in range(cycles):
            self._fresh(train)
            self._turn(train, self._advance(train, fraction), deliver=False)
            self._close()

    @precondition(lambda self: any(self.world.status(t) == TrainStatus.LOST for t in range(1, TRAINS + 1)))
    @rule(
        pick=st.integers(min_value=0, max_value=TRAINS - 1),
        where=fractions,
        backward=st.booleans(),
        deliver=st.booleans(),
    )
    def moved_while_lost(self, pick: int, where: float, backward: bool, deliver: bool) -> None:
        # SPEC §4 step 5: a lost train is found outside its zone (it moved while lost): beyond its
        # end, or rolled back behind its start, never into another train.
        lost = [t for t in range(1, TRAINS + 1) if self.world.status(t) == TrainStatus.LOST]
        train = lost[pick % len(lost)]
        self._fresh(train)
        zone = self.world.zone(train)
        if zone is None or self.world.status(train) != TrainStatus.LOST:
            return  # re-detected when the cycle closed
        x = self.world.fronts[train - 1]
        length = LINE.train_length_m
        if backward:
            # Rolled back, but not into what the follower may reach: its authority, bounded by
            # the zone while the train is lost (the paper's scheme cannot protect more).
            reach = max((self.world.reach_m(t) for t in range(1, train)), default=0.0)
            reach = max(reach, zone.start_m - LINE.params.safety_margin_m)
            low, high = reach + length, min(zone.start_m + length - 0.5, x)
        else:
            low, high = max(zone.end_m + 1.0, x), self.world.room_m(train)
        if low > high:
            return  # no room outside its zone on that side
        self._turn(train, low + where * (high - low), deliver=deliver, moved_while_lost=True)

    @precondition(lambda self: any(self.world.status(t) == TrainStatus.FLAGGED for t in range(1, TRAINS + 1)))
    @rule(pick=st.integers(min_value=0, max_value=TRAINS - 1))
    def manual_release(self, pick: int) -> None:
        # SPEC §4 step 5: the operator releases a flagged train after visual confirmation.
        flagged = [t for t in range(1, TRAINS + 1) if self.world.status(t) == TrainStatus.FLAGGED]
        self.world.release(flagged[pick % len(flagged)])

    @rule()
    def advance_time(self) -> None:
        # The trains without a turn stand and report; the controller's timers run to the next cycle.
        self._close()

    # ------------------------------------------------------------------ invariants

    @invariant()
    def safety_invariants_hold(self) -> None:
        for before, step, after in self.unchecked:
            for inv in INVARIANTS:
                message = inv.check(before, step, after, LINE)
                assert message is None, f"{inv.name} at t={step.t_s:g} s: {message}"
        self.unchecked.clear()

    @invariant()
    def physically_apart(self) -> None:
        # The model itself: trains never overlap (they obey their authorities, or move only
        # within the room ahead when lost).
        fronts = self.world.fronts
        for a, b in zip(fronts, fronts[1:], strict=False):
            assert b - LINE.train_length_m >= a - 1e-6, fronts


ZoneControllerMachine.TestCase.settings = settings(max_examples=50, stateful_step_count=40, deadline=None)
TestZoneController = ZoneControllerMachine.TestCase
