"""Run the bad-input sweep of ``tests/bad_inputs.py`` and print a summary.

    python benchmarks/bad_input_sweep.py [--jobs 2] [-k SUBSTRING] [--slowest 10]

Every case runs the real command (``python -m railstop.cli ...`` or ``python -m railstop.link.udp
...``) in a fresh temporary folder, ``--jobs`` at a time. A case passes when the command exits with
code 2 and prints exactly one non-empty line on stderr, starting with ``error: `` and containing the
case's substrings, and no traceback. The summary counts the cases, those that pass, those that
printed a traceback and the others, and lists every case that did not pass with its first stderr
lines. Exit code 0 only when every case passes.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import ModuleType
from typing import Any

CASES_FILE = Path(__file__).resolve().parent.parent / "tests" / "bad_inputs.py"


def load_cases() -> ModuleType:
    """``tests/bad_inputs.py`` as a module (the tests folder is no package)."""
    spec = importlib.util.spec_from_file_location("bad_inputs", CASES_FILE)
    if spec is None or spec.loader is None:
        raise SystemExit(f"cannot load {CASES_FILE}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the file runs
    spec.loader.exec_module(module)
    return module


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2, help="cases run at a time (default 2)")
    parser.add_argument("-k", dest="select", default="", help="only the cases whose id contains this")
    parser.add_argument("--slowest", type=int, default=5, help="list this many slowest cases")
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs must be at least 1 (got {args.jobs})")

    bad = load_cases()
    cases = [c for c in bad.CASES if args.select in c.id]
    if not cases:
        parser.error(f"no case id contains {args.select!r}")

    def one(case: Any) -> Any:
        with tempfile.TemporaryDirectory(prefix="railstop-bad-") as where:
            return bad.run_case(case, Path(where))

    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        outcomes = list(pool.map(one, cases))
    wall = time.perf_counter() - t0

    ok = [o for o in outcomes if o.verdict == "ok"]
    tracebacks = [o for o in outcomes if o.verdict == "traceback"]
    other = [o for o in outcomes if o.verdict == "other"]
    width = max(len(o.case.id) for o in outcomes)
    for title, group in (("traceback", tracebacks), ("other", other)):
        for o in group:
            print(f"{title:<9}  {o.case.id:<{width}}  {'; '.join(o.problems())}")
            print(f"           $ {o.case.shell()}")
            for line in (o.lines or ["(stderr empty)"])[:3]:
                print(f"           | {line[:300]}")
    if args.slowest > 0:
        print(f"\nslowest {min(args.slowest, len(outcomes))} cases:")
        for o in sorted(outcomes, key=lambda o: -o.seconds)[: args.slowest]:
            print(f"  {o.seconds:6.2f} s  {o.case.id}")
    rows = (
        ("cases", len(outcomes)),
        ("one error line + exit 2", len(ok)),
        ("traceback", len(tracebacks)),
        ("other", len(other)),
    )
    print()
    for label, n in rows:
        print(f"{label:<24} {n:>5}")
    print(f"{'wall time':<24} {wall:>5.0f} s ({args.jobs} at a time)")
    return 0 if len(ok) == len(outcomes) else 1


if __name__ == "__main__":
    sys.exit(main())
