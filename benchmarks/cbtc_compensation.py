"""SPEC §4 position compensation, measured: how far the onboard authority ends beyond the intended end.

    python benchmarks/cbtc_compensation.py [--duration-s 20] [--seed 1]

A train runs at a constant speed towards a train standing far ahead; the real
units talk over the real radio (``railstop.wayside.zone_controller``,
``railstop.onboard.cbtc``, ``railstop.link.cbtc_radio`` with the ``cbtc-radio``
medium, on ``railstop.clock``). The zone controller means the authority
to end ``safety_margin_m`` behind the standing train's rear less both trains'
location uncertainty and the rollback allowance; it sends the distance from
Pc = Pp + Δt·Vp and Δt, and the onboard unit rebuilds Pc from its own copy of
the report the command answers. The **overshoot** is how far beyond that
intended end the onboard unit's authority ends, for every command it takes
(0 or less: never beyond). Printed over a sweep of speeds 0-90 km/h and
processing delays Δt 0-1 s, with the maximum over the sweep; and, for
comparison, the end the old reading gave (the distance added to where the
train is when the command arrives).
"""

from __future__ import annotations

import argparse
import statistics

from railstop.clock import SimClock
from railstop.config.layout import Cbtc
from railstop.link.cbtc_radio import CbtcRadio
from railstop.link.channel import media_preset
from railstop.messages import Message, MovementCommand, OnboardPosition, Output, PositionReport
from railstop.onboard.cbtc import OnboardCbtc
from railstop.wayside.zone_controller import ZoneController

LENGTH_M = 120.0
OBSTACLE_FRONT_M = 100_000.0  # far ahead: the train never gets near it
UNCERTAINTY_M = 8.0
SPEEDS_KMH = (0.0, 10.0, 30.0, 50.0, 70.0, 80.0, 90.0)
DELAYS_S = (0.0, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0)


class _Recording(OnboardCbtc):
    """The onboard unit, noting its authority's end after each command it takes, and where the
    old reading (here + distance) would have put it."""

    taken: list[tuple[float, float, float]]

    def handle(self, message: Message, now_s: float) -> list[Output]:
        before = self.commands
        here = self.position_m
        out = super().handle(message, now_s)
        if isinstance(message, MovementCommand) and self.commands > before:
            # With the uncertainty it reported in the report the command answers.
            self.taken.append((self.authority_end_m, here + message.authority_m, self.held_uncertainty_m))
        return out


def overshoot(
    delay_s: float, speed_mps: float, duration_s: float, seed: int
) -> tuple[list[float], list[float]]:
    """(onboard end - intended end, old reading's end - intended end) for every command taken."""
    # A report period longer than the longest Δt, so that no command is missed on the way.
    params = Cbtc(report_period_s=1.5, processing_delay_s=delay_s, missed_commands_eb=3)
    zc = ZoneController(
        params=params,
        segments=[(100.0 * k, 100.0 * (k + 1)) for k in range(1100)],
        blocks=[(1000.0 * k, 1000.0 * (k + 1)) for k in range(110)],
        overlap_m=50.0,
        train_length_m=LENGTH_M,
        line_end_m=110_000.0,
        limit_at=lambda x: speed_mps + 10.0,
        gradient_at=lambda x: 0.0,
        downlink="radio",
    )
    radio = CbtcRadio(params=media_preset("cbtc-radio"), seed=seed)
    train = _Recording(train_id=0, direction="R", params=params, curve_decel_mps2=1.0, uplink="radio")
    train.taken = []
    standing = OnboardCbtc(train_id=1, direction="R", params=params, curve_decel_mps2=1.0, uplink="radio")
    clock = SimClock([zc, radio, train, standing], step_s=0.01)

    def plant(now_s: float, dt: float) -> list[Output]:
        return [
            Output(
                to=train.name,
                message=OnboardPosition(
                    position_m=1000.0 + speed_mps * now_s, speed_mps=speed_mps, uncertainty_m=UNCERTAINTY_M
                ),
            ),
            Output(
                to=standing.name,
                message=OnboardPosition(
                    position_m=OBSTACLE_FRONT_M, speed_mps=0.0, uncertainty_m=UNCERTAINTY_M
                ),
            ),
        ]

    # The standing train reports first, so the moving one's authority ends behind it from the start.
    clock.deliver(
        [
            Output(
                to="radio",
                message=PositionReport(
                    train_id=1,
                    position_m=OBSTACLE_FRONT_M,
                    speed_mps=0.0,
                    direction="R",
                    time_s=0.0,
                    uncertainty_m=UNCERTAINTY_M,
                ),
            )
        ]
    )
    clock.run(duration_s, plant)
    # The rear of the train ahead less its uncertainty and the rollback, the margin, and the
    # follower's own uncertainty as it reported it (on the telegram's grid, rounded up).
    limit = OBSTACLE_FRONT_M - LENGTH_M - UNCERTAINTY_M - params.rollback_m - params.safety_margin_m
    return [end - (limit - own) for end, _, own in train.taken], [
        old - (limit - own) for _, old, own in train.taken
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration-s", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    print("authority overshoot, cbtc-radio medium (m; + = beyond the intended end, 0 or less: never beyond)")
    head = (
        f"{'km/h':>5} {'Δt s':>5} | {'anchored: max':>13} {'mean':>7} | {'old reading: max':>16} {'mean':>6}"
    )
    print(head + " | commands")
    worst, worst_old, n = -float("inf"), -float("inf"), 0
    for kmh in SPEEDS_KMH:
        for delay in DELAYS_S:
            on, old = overshoot(delay, kmh / 3.6, args.duration_s, args.seed)
            worst, worst_old, n = max(worst, *on), max(worst_old, *old), n + len(on)
            print(
                f"{kmh:5.0f} {delay:5.1f} | {max(on):13.3f} {statistics.fmean(on):7.3f} | "
                f"{max(old):16.3f} {statistics.fmean(old):6.3f} | {len(on)}"
            )
    print(
        f"max overshoot over the sweep: {max(worst, 0.0):.3f} m "
        f"({n} commands; largest end - intended {worst:.3f} m)"
    )
    print(f"the old reading (here + distance): max overshoot {worst_old:.3f} m")


if __name__ == "__main__":
    main()
