"""The live CBTC line on the wall clock, measured: are the cycles on time, what does each process cost?

    python benchmarks/live_line.py [--trains 20] [--minutes 10] [--spacing-m 250]
    python benchmarks/live_line.py --probe-s 300     # the control probe alone

Runs ``railstop live run`` (office, zone controller, plant, stations, trains:
five processes over UDP on loopback, scale 1) and prints per process its plant steps, the
steps that started more than one step late (a process that could not keep
up), its CPU seconds and its share of one core; for the zone controller the
reports and commands against the cycles due (trains x duration / report
period), the trains lost; for the trains their emergency brakes; for the
office the reports stored against those sent.

Beside the run, a control probe: a sixth process with the same 10 ms wall clock
and no work (no unit, no socket, no plant). Its late steps are the host's: a
stall it shares with the live processes is not theirs. With ``--probe-s S`` the
probe runs alone for S seconds (under ``chrt -f 50`` to try real-time priority).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from railstop.config import default_line
from railstop.live.clock import TimeBase, WallClock

PROBE_STEP_S = 0.01  # the plant's and the stations' step


def probe(seconds: float) -> None:
    """A control beside the live run: the wall clock of a 10 ms process with no unit, no socket
    and no plant. Its late steps are the host's alone (prints its timing as JSON)."""
    base = TimeBase(time.time(), 1.0)
    clock = WallClock([], step_s=PROBE_STEP_S, base=base)
    asyncio.run(clock.run_live(lambda t, dt: [], lambda t: [], asyncio.Event(), until_s=seconds))
    print(json.dumps(clock.timing()))


def host_counters() -> dict[str, float]:
    """The host's stolen CPU time (``/proc/stat``, seconds) and the CPU pressure stall total
    (``/proc/pressure/cpu`` 'some', seconds), where the kernel offers them."""
    out: dict[str, float] = {}
    try:
        fields = Path("/proc/stat").read_text().splitlines()[0].split()
        out["steal_s"] = int(fields[8]) / 100.0  # USER_HZ ticks
    except (OSError, IndexError, ValueError):
        pass
    try:
        some = Path("/proc/pressure/cpu").read_text().splitlines()[0]
        out["cpu_pressure_s"] = int(some.rsplit("total=", 1)[1]) / 1e6
    except (OSError, IndexError, ValueError):
        pass
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trains", type=int, default=20)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--spacing-m", type=float, default=250.0)
    ap.add_argument("--no-tasc", action="store_true", help="point-mass stops (no stations process)")
    ap.add_argument("--probe-s", type=float, help="run only the control probe, this many seconds")
    args = ap.parse_args()
    if args.probe_s is not None:
        probe(args.probe_s)
        return
    duration = args.minutes * 60.0
    control = subprocess.Popen(
        [sys.executable, __file__, "--probe-s", str(duration)], stdout=subprocess.PIPE, text=True
    )
    host_before = host_counters()
    with tempfile.TemporaryDirectory() as tmp:
        db = str(Path(tmp) / "live.db")
        argv = [sys.executable, "-m", "railstop.cli", "live", "run", "--trains", str(args.trains)]
        argv += ["--duration-s", str(duration), "--http-port", "0", "--spacing-m", str(args.spacing_m)]
        argv += ["--no-tasc"] if args.no_tasc else []
        p = subprocess.run([*argv, "--db", db], capture_output=True, text=True, check=False)
    host_after = host_counters()
    out_probe, _ = control.communicate()
    if p.returncode != 0:
        sys.exit(f"live run failed: {p.stderr.strip()}")
    out = json.loads(p.stdout.strip().splitlines()[-1])
    period = default_line().cbtc.report_period_s
    print(f"{args.trains} trains live for {args.minutes:g} min at x1 (report period {period:g} s)")
    print(
        f"{'process':16s} {'steps':>8s} {'late':>6s} {'latest ms':>10s} {'CPU s':>8s} {'wall s':>8s} "
        f"{'CPU share':>10s}"
    )
    for role in ("zone_controller", "plant", "stations", "trains", "office"):
        if role not in out:
            continue
        r = out[role]
        steps = r.get("steps", "-")
        late = r.get("late_steps", "-")
        latest = r.get("late_max_ms", "-")  # how late its latest step started
        share = r["cpu_s"] / r["wall_s"] if r.get("wall_s") else float("nan")
        print(
            f"{role:16s} {steps!s:>8s} {late!s:>6s} {latest!s:>10s} {r['cpu_s']:8.2f} {r['wall_s']:8.1f} "
            f"{share:10.1%}"
        )
    # When the late steps were due and when the garbage collector paused (over 5 ms), in seconds
    # after the first of all these: late steps that hit every process at once point at the host.
    # The control probe: a bare 10 ms clock in a sixth process, and what the host took meanwhile.
    ctl = json.loads(out_probe.strip().splitlines()[-1])
    print(
        f"{'control probe':16s} {ctl['steps']:8d} {ctl['late_steps']:6d} {ctl['late_max_ms']!s:>10s}"
        f"   (a 10 ms clock with no work, beside the run)"
    )
    took = {k: round(host_after[k] - host_before[k], 2) for k in host_after if k in host_before}
    print(f"host meanwhile: {took or 'no counters'} (steal: CPU time the hypervisor took from this VM)")
    marks = {}
    for role in ("zone_controller", "plant", "stations", "trains"):
        if isinstance(out.get(role), dict):
            pauses = out[role].get("gc", {}).get("long_at_unix_ms", [])
            marks[role] = (out[role].get("late_at_unix", []), [t for t, _ in pauses])
    marks["control probe"] = (ctl.get("late_at_unix", []), [])
    starts = [t for late, gcs in marks.values() for t in (*late, *gcs)]
    if starts:
        t0 = min(starts)
        for role, (late, gcs) in marks.items():
            gc = out.get(role, {}).get("gc", {})
            at_late = [round(t - t0, 2) for t in late[:12]]
            at_gc = [round(t - t0, 2) for t in gcs[:12]]
            pauses = (
                f"; GC pauses over 5 ms {gc.get('over_5_ms')} (longest {gc.get('max_ms')} ms) at {at_gc}"
                if gc
                else " (no collector watched)"
            )
            print(f"{role}: late steps at {at_late}{pauses}")
    zc, fleet, office = out["zone_controller"], out["trains"], out["office"]
    due = args.trains * duration / period
    print(
        f"zone controller: {zc['reports']:,} reports and {zc['commands']:,} commands for about {due:,.0f} "
        f"cycles due, {zc['lost_trains']} train(s) lost, {zc['commands_held_at_start']} command(s) held "
        f"until every train had reported"
    )
    plant = out.get("plant")
    if isinstance(plant, dict):
        print(
            f"plant: {plant['tasc_stops']} TASC stop(s) in lock step, {plant['late_tasc_drives']:,} TASC "
            f"drive(s) late (the last one held), {plant['sensor_frames']:,} trackside frames; drives lost "
            f"{plant['drive_lost']} time(s) (once when the trains' process stops first), refused "
            f"{plant['refused'] or 'none'}"
        )
    ebs = fleet["emergency_brakes"] or "none"
    print(f"trains: emergency brakes {ebs}; radio frames rejected {fleet['radio_rejected'] or 'none'}")
    tasc = fleet.get("tasc")
    if tasc:
        print(
            f"station stops by ground TASC: {tasc['stops']}, {tasc['within_tolerance']} within the stations' "
            f"tolerance, |error| p99 {tasc['abs_error_p99_m']} m, max {tasc['abs_error_max_m']} m, emergency "
            f"brakes {tasc['emergency_brakes'] or 'none'}; telegrams delivered "
            f"{tasc['telegrams_delivered']:,}, refused {tasc['telegrams_refused'] or 'none'}"
        )
        st = out.get("stations", {})
        print(
            f"age on delivery (ms, median / p99 / max): braking telegrams {tasc.get('telegram_age_ms')}, "
            f"sensor readings {st.get('readings_age_ms') if isinstance(st, dict) else None}"
        )
    dwells = fleet.get("dwells")
    if dwells:
        platforms = out.get("stations", {}).get("platforms", {})
        print(
            f"dwells over the door link: {dwells['dwells']} ended ({dwells['outcomes'] or 'none'}), "
            f"{dwells['corrections']} correction(s), longest {dwells['dwell_s_max']} s; door frames: "
            f"{dwells['command_frames']:,} commands sent, {dwells['status_frames']:,} statuses delivered, "
            f"refused {dwells['refused'] or 'none'}; platforms: PSC answered "
            f"{platforms.get('psc_answered')}, links lost {platforms.get('links_lost')}"
        )
    sent = sum(
        out[r]["office_link"]["submitted"] for r in ("zone_controller", "stations", "trains") if r in out
    )
    print(
        f"office: {office['stored']:,} reports stored of {sent:,} sent, {office['duplicates']} duplicate(s)"
    )


if __name__ == "__main__":
    main()
