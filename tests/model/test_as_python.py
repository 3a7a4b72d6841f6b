"""The stop model run as plain Python (``NUMBA_DISABLE_JIT=1``, docs/architecture.md) gives the
compiled model's stop: the way to study a change to the model before its compile."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from railstop.config import default_line, default_vehicle
from railstop.sim.single import run_stop

_SCRIPT = """
import json, warnings
warnings.filterwarnings("ignore")  # the random streams' uint64 arithmetic wraps, as compiled
from railstop.jit import as_python
from railstop.config import default_line, default_vehicle
from railstop.sim.single import run_stop
line = default_line()
r, _ = run_stop(line=line, station=line.station("Riverside"), vehicle=default_vehicle(),
                controller="tasc-brake-controller", seed=1)
print(json.dumps({"python": as_python(), "error": r.stop_error_m, "time": r.stop_time_s,
                  "notches": r.notch_changes, "commands": r.commands}))
"""


def test_the_model_run_as_python_stops_where_the_compiled_model_stops() -> None:
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    cmd = [sys.executable, "-c", _SCRIPT]
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    got = json.loads(res.stdout.strip().splitlines()[-1])
    assert got["python"] is True
    line = default_line()
    compiled, _ = run_stop(
        line=line, station=line.station("Riverside"), vehicle=default_vehicle(),
        controller="tasc-brake-controller", seed=1,
    )  # fmt: skip
    assert abs(got["error"] - compiled.stop_error_m) < 1e-6
    assert abs(got["time"] - compiled.stop_time_s) < 1e-6
    assert (got["notches"], got["commands"]) == (compiled.notch_changes, compiled.commands)
