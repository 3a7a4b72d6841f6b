"""A CBTC line's capacity: its minimum headway from its data, and what the simulated line sustains.

    python benchmarks/cbtc_capacity.py [--trains 20] [--headways 100 105 110 115 120] [--dwell-s 25]
        [--handover platform-clear|predictive] [--regulation] [--seed 1]

First the analytic minimum headway of every platform (``railstop.sim.capacity``: the nominal
dwell, the leader's clearing, the system's delays, the follower's run-in from its best release
state on its approach to its waiting point, its approach from the hand-over), with each train's
location uncertainty at the line data's declared bound, and beside it the bound of a clairvoyant
follower (at the hand-over at the zone's entry speed when released); the line's is the largest.

Then the line under moving-block CBTC (``railstop line run --signalling cbtc``, the nominal set)
with ``--trains`` trains entering at each headway of ``--headways`` and at 90 s (entries faster
than any platform serves: the queued line, whose busiest platform's interval is the line's
capacity). Per run: the median interval between consecutive arrivals at the busiest platform
(over the trains after the first three, which meet an empty line), whether the line kept the
entry headway (that median within 2 % of it), the trains per hour and the mean delay, the onboard
units' emergency brakes (EB: a failed prediction, a lost command) and the authority overlaps and
collisions ("unsafe").

``--dwell-s`` sets every station's dwell (the operation's own otherwise: 30 s, 40 s at
Hillcrest). ``--handover predictive``: the line's opt-in rule that hands a follower to its
station stop behind a leaving train (``LineSettings.handover``), with its own analytic minimum.
``--regulation``: the ATS holds trains at their platforms rather than let them stand before the
next (``LineSettings.regulation``).

Last, per run, where the busiest platform's cycle goes beyond its dwell: the follower's mean time
from the leader's departure to its own arrival, against the analytic clear + system + run-in +
approach, for the followers still moving at that departure and for those standing, held for the
platform; and the queued line's interval against the analytic minimum.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from railstop.config import load_line, load_vehicle
from railstop.config.operation import StationDwell, load_operation
from railstop.config.schema import Line
from railstop.sim.capacity import minimum_headways
from railstop.sim.line import LineSettings, LineSimulation, StopRecord

KEPT = 1.02  # the line kept its entry headway: the busiest platform's median interval within 2 %
WARM_UP = 3  # the first trains meet an empty line


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trains", type=int, default=20)
    ap.add_argument("--headways", type=float, nargs="+", default=[100.0, 105.0, 110.0, 115.0, 120.0])
    ap.add_argument("--dwell-s", type=float, default=None)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--handover",
        default="platform-clear",
        help="platform-clear (the line's rule) or predictive (LineSettings.handover)",
    )
    ap.add_argument(
        "--regulation",
        action="store_true",
        help="the ATS holds trains at their platforms rather than before the next (LineSettings.regulation)",
    )
    args = ap.parse_args()
    line, vehicle = load_line(None), load_vehicle(None)
    operation = load_operation(None, line)
    if args.dwell_s is not None:
        operation = operation.model_copy(
            update={
                "dwell_s": args.dwell_s,
                "stations": [StationDwell(name=s.name, dwell_s=args.dwell_s) for s in operation.stations],
            }
        )
    rows = minimum_headways(line, vehicle, operation, handover=args.handover)
    print(
        f"analytic minimum headway ({operation.controller}, hand-over {args.handover}, "
        f"dwell {operation.dwell_s:g} s"
        f"{'' if args.dwell_s is not None else ', Hillcrest 40 s'}; location uncertainty "
        f"{line.cbtc.position_uncertainty_m:g} m):"
    )
    print(
        f"{'platform':12s} {'dwell':>7s} {'clear':>7s} {'system':>7s} {'run-in':>7s} {'approach':>9s} "
        f"{'released at':>17s} {'headway':>9s} {'trains/h':>9s} {'clairvoyant':>12s}"
    )
    for h in rows:
        where = f"{h.release_m:5.1f} m, {h.release_kmh:4.1f} km/h"
        print(
            f"{h.station:12s} {h.dwell_s:6.2f}s {h.clear_s:6.2f}s {h.system_s:6.2f}s {h.run_in_s:6.2f}s "
            f"{h.approach_s:8.2f}s {where:>17s} {h.headway_s:8.2f}s {h.trains_per_hour:9.2f} "
            f"{h.ideal_headway_s:11.2f}s"
        )
    worst = max(rows, key=lambda h: h.headway_s)
    print(f"line: {worst.headway_s:.2f} s at {worst.station} ({worst.trains_per_hour:.2f} trains/h)")
    print()
    print(
        f"simulated line, {args.trains} trains, cbtc, hand-over {args.handover}"
        f"{', regulated' if args.regulation else ''}, nominal set, "
        f"seed {args.seed}: "
        "the busiest platform's median arrival interval"
    )
    print(
        f"{'entry headway':>13s} {'busiest':>10s} {'interval':>9s} {'kept':>5s} {'vs analytic':>11s} "
        f"{'trains/h':>9s} {'mean delay':>10s} {'EB':>4s} {'unsafe':>6s} {'wall':>6s}"
    )
    kept_best = None
    splits: list[tuple[float, str, dict[str, list[float]]]] = []
    served: list[tuple[float, float]] = []  # (entry headway, the busiest platform's interval)
    for headway in [*args.headways, 90.0]:
        t0 = time.perf_counter()
        op = operation.model_copy(update={"trains": args.trains, "headway_s": headway})
        sim = LineSimulation(
            line=line,
            vehicle=vehicle,
            operation=op,
            seed=args.seed,
            settings=LineSettings(signalling="cbtc", handover=args.handover, regulation=args.regulation),
        )
        summary = sim.run(max(3600.0, headway * args.trains + 900.0)).summary()
        intervals = {}
        for st in line.stations:
            arrivals = sorted(s.arrive_s for s in sim.stops if s.station == st.name)
            d = np.diff(arrivals)[WARM_UP:]
            if d.size:
                intervals[st.name] = float(np.median(d))
        busiest = max(intervals, key=lambda k: intervals[k])
        interval = intervals[busiest]
        splits.append((headway, busiest, _follow_split(sim, line, busiest)))
        served.append((headway, interval))
        kept = interval <= KEPT * headway
        if kept and (kept_best is None or headway < kept_best):
            kept_best = headway
        c = summary["cbtc"]
        print(
            f"{headway:12.1f}s {busiest:>10s} {interval:8.1f}s {'yes' if kept else 'no':>5s} "
            f"{interval / worst.headway_s - 1.0:+10.1%} {summary['trains_per_hour']:9.2f} "
            f"{summary['mean_delay_s']:9.1f}s {c['onboard_emergency_brakes']:4d} "
            f"{c['authority_overlaps'] + c['collisions']:4d} {time.perf_counter() - t0:5.0f}s",
            flush=True,
        )
    by_name = {h.station: h for h in rows}
    print()
    print(
        "the busiest platform's cycle split: the follower's time from the leader's departure to its "
        "own arrival (the analytic clear + system + run-in + approach), for the followers still moving then "
        "and for those standing, held for the platform"
    )
    print(f"{'entry headway':>13s} {'busiest':>10s} {'analytic':>9s} {'moving':>15s} {'standing':>15s}")
    for headway, name, split in splits:
        h = by_name[name]
        cells = [
            f"{len(v):3d} x {np.mean(v):6.1f}s" if v else f"{0:3d} x {'-':>6s} "
            for v in (split["moving"], split["standing"])
        ]
        follow = h.follow_s
        print(f"{headway:12.1f}s {name:>10s} {follow:8.1f}s {cells[0]:>15s} {cells[1]:>15s}")
    queued = next(interval for headway, interval in served if headway == 90.0)
    print(
        f"fed every 90 s (faster than it serves), the busiest platform serves one train every "
        f"{queued:.1f} s, {queued / worst.headway_s - 1.0:+.1%} over the analytic {worst.headway_s:.2f} s"
    )
    if kept_best is None:
        print("the line kept none of these entry headways")
    else:
        over = kept_best / worst.headway_s - 1.0
        print(f"smallest entry headway kept: {kept_best:.1f} s, {over:+.1%} over the analytic", end=" ")
        print(f"{worst.headway_s:.2f} s")


def _served(stop: StopRecord) -> bool:
    """A station stop taken over and served as planned: within the tolerance, no emergency brake."""
    return stop.within_tolerance and stop.emergency_brake is None and not stop.by_ato


def _follow_split(sim: LineSimulation, line: Line, name: str) -> dict[str, list[float]]:
    """At platform ``name``, for each train after the first WARM_UP + 1 (where both its stop and
    the one before it were served, ``_served``): the time from the departure of the train before it
    (its first move after its stop) to its own arrival, split by where the follower was at that
    departure: still moving ("moving"), or standing between the station before and this platform's
    first detector, held for the platform ("standing")."""
    k = [s.name for s in line.stations].index(name)
    station = line.stations[k]
    first_detector = station.detector_positions_m()[0]
    behind = line.stations[k - 1].stop_point_m + 10.0 if k else -np.inf
    stops = sorted((s for s in sim.stops if s.station == name), key=lambda s: s.arrive_s)
    out: dict[str, list[float]] = {"moving": [], "standing": []}
    for leader, follower in list(zip(stops, stops[1:], strict=False))[WARM_UP:]:
        if not (_served(leader) and _served(follower)):
            continue  # an emergency brake, a stop outside the tolerance or the ATO's: not a cycle
        lt = sim.trains[leader.train]
        t = np.asarray(lt.samples_t)
        x = np.asarray(lt.samples_x)
        after = np.flatnonzero((t > leader.arrive_s) & (x > x[np.searchsorted(t, leader.arrive_s)] + 0.01))
        if not after.size:
            continue
        departed = float(t[after[0]])
        ft = np.asarray(sim.trains[follower.train].samples_t)
        fx = np.asarray(sim.trains[follower.train].samples_x)
        i = min(np.searchsorted(ft, departed), ft.size - 1)
        j = max(np.searchsorted(ft, departed - 1.0), 0)
        standing = abs(fx[i] - fx[j]) < 0.01 and behind < fx[i] < first_detector
        out["standing" if standing else "moving"].append(follower.arrive_s - departed)
    return out


if __name__ == "__main__":
    main()
