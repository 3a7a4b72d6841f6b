"""SPEC §4 position compensation, measured: the authority's slack with and without Pc.

    python benchmarks/cbtc_compensation.py [--speed-kmh 80] [--duration-s 60]

A train runs at a constant speed towards a train standing far ahead; the real
units talk over the real radio (``railstop.wayside.zone_controller``,
``railstop.onboard.cbtc``, ``railstop.link.cbtc_radio`` with the ``cbtc-radio``
medium, on ``railstop.sim.clock``). The zone controller means the authority
to end ``safety_margin_m`` behind the standing train's rear; the train takes
the command's distance from where it is when the command arrives. The
**slack** is how far beyond the intended end the train then believes its
authority reaches: with compensation (Pc = Pp + Δt·Vp) only the radio's
latency is left uncompensated; without it, Δt·Vp more. Positive slack eats
the safety margin. Printed for Δt = 0.1 .. 0.5 s, compensation on and off.
"""

from __future__ import annotations

import argparse
import statistics

from railstop.config.layout import Cbtc
from railstop.link.cbtc_radio import CbtcRadio
from railstop.link.channel import media_preset
from railstop.messages import Message, MovementCommand, OnboardPosition, Output, PositionReport
from railstop.onboard.cbtc import OnboardCbtc
from railstop.sim.clock import SimClock
from railstop.wayside.zone_controller import ZoneController

LENGTH_M = 120.0
OBSTACLE_FRONT_M = 100_000.0  # far ahead: the train never gets near it


class _Recording(OnboardCbtc):
    """The onboard unit, noting where it stands when each command arrives."""

    received: list[tuple[float, float]]

    def handle(self, message: Message, now_s: float) -> list[Output]:
        if isinstance(message, MovementCommand) and message.train_id == self.train_id:
            self.received.append((self.position_m, message.authority_m))
        return super().handle(message, now_s)


def slack(delay_s: float, compensate: bool, speed_mps: float, duration_s: float, seed: int) -> list[float]:
    params = Cbtc(processing_delay_s=delay_s, compensate=compensate)
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
    train.received = []
    standing = OnboardCbtc(train_id=1, direction="R", params=params, curve_decel_mps2=1.0, uplink="radio")
    clock = SimClock([zc, radio, train, standing], step_s=0.01)

    def plant(now_s: float, dt: float) -> list[Output]:
        return [
            Output(
                to=train.name,
                message=OnboardPosition(position_m=1000.0 + speed_mps * now_s, speed_mps=speed_mps),
            ),
            Output(to=standing.name, message=OnboardPosition(position_m=OBSTACLE_FRONT_M, speed_mps=0.0)),
        ]

    # The standing train reports first, so the moving one's authority ends behind it from the start.
    clock.deliver(
        [
            Output(
                to="radio",
                message=PositionReport(
                    train_id=1, position_m=OBSTACLE_FRONT_M, speed_mps=0.0, direction="R", time_s=0.0
                ),
            )
        ]
    )
    clock.run(duration_s, plant)
    intended = OBSTACLE_FRONT_M - LENGTH_M - params.safety_margin_m
    return [here + authority - intended for here, authority in train.received]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--speed-kmh", type=float, default=80.0)
    ap.add_argument("--duration-s", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    v = args.speed_kmh / 3.6
    print(f"authority slack at {args.speed_kmh:g} km/h, cbtc-radio medium (m; + = beyond the intended end)")
    head = f"{'Δt s':>6} {'Δt·Vp m':>8} | {'with Pc: mean':>13} {'max':>6} | {'without: mean':>13} {'max':>6}"
    print(head + " | commands")
    for delay in (0.1, 0.2, 0.3, 0.4, 0.5):
        on = slack(delay, True, v, args.duration_s, args.seed)
        off = slack(delay, False, v, args.duration_s, args.seed)
        print(
            f"{delay:6.1f} {delay * v:8.2f} | {statistics.fmean(on):13.2f} {max(on):6.2f} | "
            f"{statistics.fmean(off):13.2f} {max(off):6.2f} | {len(on)}, {len(off)}"
        )


if __name__ == "__main__":
    main()
