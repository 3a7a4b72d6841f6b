"""Precise-stop confirmation (SPEC §5 fig. 3), a pure unit on the train.

After a stop the ATC checks that the train really is at standstill (zero
velocity relay), then sends PSC to the WPCS. A reply makes PSC high and the
door data exchange starts. No reply within the time-out means the train is not
in position: position correction (a short creep forward or back, as the
platform lamps F / R of SPEC §3 would ask), then a new PSC request.
[interpretation] "after 3 attempts without PSC" = 3 PSC requests without a
reply: the third failure reports a fault and applies the emergency brake
(so at most 2 corrections).

Phases and inputs are ``Enum``s, the transitions a table (DESIGN rule 2). The
unit turns the time-out that uses up the last attempt into its own input
(``PSC_TIMEOUT_LAST``), so that the counting rule is visible in the table.
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import StrEnum
from types import MappingProxyType
from typing import NamedTuple

from railstop.errors import InterlockError


class StopPhase(StrEnum):
    RUNNING = "running"  # moving, no stop to confirm (between stations, departed)
    PSC_WAIT = "psc-wait"  # at standstill, PSC request sent, waiting for the WPCS
    CORRECTING = "correcting"  # no reply: position correction (creep) ordered
    CONFIRMED = "confirmed"  # PSC high: door data exchange with the WPCS
    FAULT = "fault"  # attempts used up: fault reported, emergency brake


class StopInput(StrEnum):
    STANDSTILL = "standstill"  # the ZVR confirms zero speed
    PSC_REPLY = "psc-reply"
    PSC_TIMEOUT = "psc-timeout"
    PSC_TIMEOUT_LAST = "psc-timeout-last"  # the time-out of the last allowed attempt
    DEPART = "depart"  # start enable given, the train leaves
    LINK_LOST = "link-lost"  # PSC high, but no valid PSD status from the WPCS within the time-out


P = StopPhase
I = StopInput  # noqa: E741

STOP_TRANSITIONS: Mapping[tuple[StopPhase, StopInput], StopPhase] = MappingProxyType(
    {
        (P.RUNNING, I.STANDSTILL): P.PSC_WAIT,  # SPEC §5: standstill checked, then PSC sent
        (P.PSC_WAIT, I.PSC_REPLY): P.CONFIRMED,  # SPEC §5: reply -> PSC high
        (P.PSC_WAIT, I.PSC_TIMEOUT): P.CORRECTING,  # SPEC §5: no reply -> position correction
        (P.PSC_WAIT, I.PSC_TIMEOUT_LAST): P.FAULT,  # SPEC §5: 3 attempts -> fault + emergency brake
        (P.CORRECTING, I.STANDSTILL): P.PSC_WAIT,  # after the creep: a new attempt
        (P.CONFIRMED, I.DEPART): P.RUNNING,
        # SPEC §5: the PSD state is trusted only while PSC is high, and PSC is the live exchange.
        # [interpretation] A link that falls silent with PSC high is the fault of SPEC §5
        # (fault reported, emergency brake): the train must not leave on a PSD state it can no
        # longer see, and nothing may open on a link that is gone.
        (P.CONFIRMED, I.LINK_LOST): P.FAULT,
    }
)


class StopConfirmState(NamedTuple):
    phase: StopPhase = StopPhase.RUNNING
    failed: int = 0  # PSC requests of this stop left without a reply

    @property
    def attempts(self) -> int:
        """PSC requests sent at this stop."""
        return self.failed + (1 if self.phase in (StopPhase.PSC_WAIT, StopPhase.CONFIRMED) else 0)

    @property
    def psc(self) -> bool:
        return self.phase == StopPhase.CONFIRMED

    @property
    def psc_request(self) -> bool:
        return self.phase == StopPhase.PSC_WAIT

    @property
    def creep(self) -> bool:
        return self.phase == StopPhase.CORRECTING

    @property
    def emergency_brake(self) -> bool:
        return self.phase == StopPhase.FAULT


def step(
    state: StopConfirmState,
    inp: StopInput,
    *,
    max_attempts: int = 3,
    table: Mapping[tuple[StopPhase, StopInput], StopPhase] = STOP_TRANSITIONS,
) -> StopConfirmState:
    """The next state, or ``InterlockError`` for an input the table does not allow."""
    if max_attempts < 1:
        raise InterlockError(f"max_attempts: must be at least 1 (got {max_attempts})")
    key = inp
    failed = state.failed
    if inp == StopInput.PSC_TIMEOUT:
        # Capped: a table that never gives up must not make the count (and the state space) endless.
        failed = min(failed + 1, max_attempts)
        if failed >= max_attempts:
            key = StopInput.PSC_TIMEOUT_LAST
    elif inp == StopInput.DEPART:
        failed = 0  # the next stop starts afresh
    nxt = table.get((state.phase, key))
    if nxt is None:
        raise InterlockError(
            f"stop confirmation: input {key.value!r} is not allowed in phase {state.phase.value!r}"
        )
    return StopConfirmState(phase=nxt, failed=failed)


def safe(state: StopConfirmState) -> StopConfirmState:
    """DESIGN rule 10: fault reported, emergency brake."""
    return state._replace(phase=StopPhase.FAULT)


class StopConfirm:
    """The unit as an object: safe state (fault, emergency brake) first, then ``InterlockError``."""

    def __init__(
        self,
        *,
        max_attempts: int = 3,
        table: Mapping[tuple[StopPhase, StopInput], StopPhase] = STOP_TRANSITIONS,
    ) -> None:
        self.state = StopConfirmState()
        self.max_attempts = max_attempts
        self.table = table

    def handle(self, inp: StopInput) -> StopConfirmState:
        try:
            self.state = step(self.state, inp, max_attempts=self.max_attempts, table=self.table)
        except InterlockError:
            self.state = safe(self.state)
            raise
        return self.state
