"""Every signal form, every TASC controller, every default station: does the train stop?

    python benchmarks/tasc_forms.py [--detectors-only] [--forms 1-8] [--verbose]

The single-stop targets of the ground-TASC issue, measured with the detailed
stop (``railstop stop --form N --controller C --station S``): the nominal stop
within ±0.10 m, and at crush load with brakes 15 % weak (``--load-factor 1
--brake-gain 0.85``) within ±0.35 m. ``--detectors-only`` runs the SPEC §1
variant without the Doppler radar (the station's zone with ``doppler`` removed).
Prints one line per form and controller (the worst error of the 4 stations in
each case, and how many of the 8 stops met their band), then the totals.
"""

from __future__ import annotations

import argparse
import time

from railstop.config import default_line, default_vehicle
from railstop.controllers import TASC_CONTROLLERS
from railstop.sim.single import run_stop
from railstop.wayside.tasc_unit import FORM_NAMES, SignalForm

CASES = (("nominal", 0.0, 1.0, 0.10), ("crush, brake 0.85", 1.0, 0.85, 0.35))


def _forms(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--detectors-only", action="store_true")
    parser.add_argument("--forms", type=_forms, default=_forms("1-8"))
    parser.add_argument("--verbose", action="store_true", help="Print every stop.")
    args = parser.parse_args()
    line, vehicle = default_line(), default_vehicle()
    if args.detectors_only:
        line = line.model_copy(update={"stations": [st.detectors_only() for st in line.stations]})
    variant = "detectors only (no Doppler)" if args.detectors_only else "detectors + Doppler"
    print(f"{line.line.name}, {variant}: nominal within ±0.10 m, crush + brake 0.85 within ±0.35 m")
    print(f"{'form':<44} {'controller':<22} {'worst nominal':>13} {'worst crush':>11} {'met':>5}")
    t0 = time.perf_counter()
    met_all = total = 0
    for form in args.forms:
        for controller in TASC_CONTROLLERS:
            worst = {label: 0.0 for label, *_ in CASES}
            met = n = 0
            for st in line.stations:
                for label, load, gain, band in CASES:
                    result, _ = run_stop(
                        line=line,
                        station=st,
                        vehicle=vehicle,
                        controller=controller,
                        seed=1,
                        load_factor=load,
                        brake_gain=gain,
                        form=SignalForm(form),
                    )
                    err = result.stop_error_m
                    ok = result.stopped and abs(err) <= band
                    met += ok
                    n += 1
                    if not result.stopped or abs(err) > abs(worst[label]):
                        worst[label] = err if result.stopped else float("inf")
                    if args.verbose:
                        print(f"    {st.name:<10} {label:<18} {err:+9.3f} m {'ok' if ok else 'MISS'}")
            name = f"{form} {FORM_NAMES[SignalForm(form)]}"[:44]
            print(
                f"{name:<44} {controller:<22} {worst['nominal']:+13.3f} {worst['crush, brake 0.85']:+11.3f} "
                f"{met:>2}/{n}",
                flush=True,
            )
            met_all += met
            total += n
    print(f"stops within their band: {met_all} of {total} ({time.perf_counter() - t0:.1f} s)")


if __name__ == "__main__":
    main()
