"""The stop model on a GPU (railstop.model.gpu), tested in numba's CUDA simulator (CI has no GPU).

In the simulator each GPU thread runs in Python and the model through its CPU
compilation, so the runs are bit-identical to the CPU's: these tests check the
kernel's wiring (each thread's work arrays, its run, its rows of the outputs)
and the campaign's ``--device gpu`` path end to end. What only a GPU shows
(libdevice's last bits, the throughput) is measured by
``benchmarks/gpu_throughput.py`` on a GPU machine.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from railstop.config import default_line, default_vehicle
from railstop.model.build import KernelModel
from railstop.model.gpu import Shapes, _kernel_source
from railstop.model.records import STATE_FIELDS, StopState, state_shape
from railstop.model.run import block_state

EXE = [sys.executable, "-m", "railstop.cli"]


def _model(controller: str) -> KernelModel:
    line = default_line()
    return KernelModel.create(
        station=line.stations[0],
        vehicle=default_vehicle(),
        controller=controller,
        form=None,
        dt_s=0.01,
        max_time_s=150.0,
        track=line.track,
    )


@pytest.mark.parametrize("controller", ["tasc-pwm", "ato-corrected", "driver-atc2"])
def test_the_kernels_work_arrays_are_the_cpus(controller: str) -> None:
    """One list of work arrays: each thread's local arrays have the CPU state's fields, shapes and
    dtypes, so a field added to the state cannot be missing on the device."""
    model = _model(controller)
    sc = np.zeros((1, 21))
    sc[0, 4] = 0.4  # a dead time of 0.4 s: a ring of 41 steps at least ...
    shapes = Shapes.of(model, sc)
    assert shapes.ring == 64  # ... rounded up: every chunk's draws share one kernel
    sc[0, 4] = 0.7
    assert Shapes.of(model, sc).ring == 128
    cpu = block_state(model, shapes.ring)
    assert [name for name, _, _, _ in STATE_FIELDS] == list(StopState._fields)
    source = _kernel_source(shapes)
    compile(source, "<kernel>", "exec")  # the generated kernel is valid Python
    for i, (name, shape, dtype, _) in enumerate(STATE_FIELDS):
        arr = getattr(cpu, name)
        dims = state_shape(shape, shapes.sizes())
        assert arr.shape == dims, name
        assert arr.dtype == dtype, name
        assert f"    {name} = cuda.local.array({dims!r}, DTYPES[{i}])" in source, name
    assert "    pending[i] = NAN" in source and "    ring[i] = 0.0" in source


def _railstop(args: list[str], cwd: Path, *, simulated: bool) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ)
    if simulated:
        env["NUMBA_ENABLE_CUDASIM"] = "1"
    else:
        env.pop("NUMBA_ENABLE_CUDASIM", None)
    return subprocess.run([*EXE, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


def test_compare_on_the_simulated_gpu_equals_the_cpu(tmp_path: Path) -> None:
    """``compare --device gpu`` (TASC, ATO with SPEC §2 corrections, a driver) in the CUDA
    simulator: every run's row equal to the CPU's, chunks of several runs and a chunk cut short."""
    common = ["compare", "--controllers", "tasc-pwm,ato-corrected,driver-ats", "--runs", "5"]
    common += ["--chunk-size", "3", "--seed", "11", "--json"]
    cpu = _railstop([*common, "--out", "cpu", "--db", "cpu.db"], tmp_path, simulated=False)
    assert cpu.returncode == 0, cpu.stderr
    gpu = _railstop([*common, "--out", "gpu", "--db", "gpu.db", "--device", "gpu"], tmp_path, simulated=True)
    assert gpu.returncode == 0, gpu.stderr
    for controller in ("tasc-pwm", "ato-corrected", "driver-ats"):
        a = pq.read_table(tmp_path / "cpu" / controller / "runs.parquet")
        b = pq.read_table(tmp_path / "gpu" / controller / "runs.parquet")
        assert a.num_rows == b.num_rows == 5
        assert a.column_names == b.column_names
        for name in a.column_names:
            x, y = a.column(name).to_numpy(), b.column(name).to_numpy()
            same = np.array_equal(x, y, equal_nan=True) if x.dtype.kind == "f" else np.array_equal(x, y)
            assert same, (controller, name, x, y)
        manifest = json.loads((tmp_path / "gpu" / controller / "campaign.json").read_text())
        assert manifest["device"] == "gpu"
        assert "device" not in json.loads((tmp_path / "cpu" / controller / "campaign.json").read_text())


def test_a_gpu_campaign_is_resumed_on_the_gpu_only(tmp_path: Path) -> None:
    args = ["campaign", "--runs", "4", "--chunk-size", "2", "--out", "c", "--db", "c.db", "--json"]
    first = _railstop([*args, "--device", "gpu"], tmp_path, simulated=True)
    assert first.returncode == 0, first.stderr
    again = _railstop([*args, "--resume"], tmp_path, simulated=False)
    assert again.returncode == 2, again.stderr
    assert "Traceback" not in again.stderr and "device" in again.stderr, again.stderr


def _one_line(p: subprocess.CompletedProcess[str], *needles: str) -> None:
    assert p.returncode == 2, (p.returncode, p.stderr)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), p.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def test_no_gpu_is_one_line_before_any_work(tmp_path: Path) -> None:
    """On a machine without a GPU (CI), ``--device gpu`` says why, exit 2, and writes nothing."""
    p = _railstop(
        ["campaign", "--runs", "3", "--device", "gpu", "--out", "c", "--db", "c.db"],
        tmp_path,
        simulated=False,
    )
    _one_line(p, "--device gpu", "GPU")
    assert not (tmp_path / "c").exists() and not (tmp_path / "c.db").exists()


def test_a_driver_error_is_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    """A GPU that fails after the start-up check (here: a machine with no driver, told that it has
    a GPU) is a SimulationError of one line, not the driver's traceback (HZ-GPU-03)."""
    from numba import cuda

    import railstop.model.gpu as gpu
    from railstop.config.scenario import Scenario
    from railstop.errors import SimulationError

    if gpu.cuda_simulated() or cuda.is_available():
        pytest.skip("this machine has a GPU (or the simulator): the launch would succeed")
    monkeypatch.setattr(gpu, "gpu_unavailable", lambda: None)
    model = _model("tasc-pwm")
    scenario = Scenario.nominal(default_line().stations[0], default_vehicle())
    with pytest.raises(SimulationError) as err:
        gpu.run_kernel_gpu(model, scenario, seed=1, first_run=0)
    message = str(err.value)
    assert message.startswith("--device gpu: the GPU failed (") and "\n" not in message, message


def test_an_unknown_device_is_one_line(tmp_path: Path) -> None:
    p = _railstop(["compare", "--runs", "3", "--device", "tpu"], tmp_path, simulated=False)
    _one_line(p, "--device", "tpu", "cpu, gpu")


def test_a_loaded_law_is_refused_on_the_gpu(tmp_path: Path) -> None:
    law = tmp_path / "law.py"
    law.write_text(
        "from railstop.control.law import control_law\n\n"
        "@control_law(name='coast')\n"
        "def coast(meas, state, params):\n"
        "    return params[0].full_service_mps2 if meas[0].distance_m < 100.0 else 0.0\n"
    )
    p = _railstop(
        ["campaign", "--law", str(law), "--controller", "coast", "--runs", "3", "--device", "gpu"],
        tmp_path,
        simulated=True,
    )
    _one_line(p, "--device gpu", "CPU only")


_ORDER_CHECK = """
import numpy as np
from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import draw_scenario, load_disturbances
from railstop.model.build import KernelModel
from railstop.model.gpu import DRAW_LAYOUTS, KernelOptions, launch_order, run_kernel_gpu
from railstop.model.run import run_kernel, scenario_arrays
from railstop.streams import RunStreams

line, vehicle = default_line(), default_vehicle()
station = line.stations[0]
model = KernelModel.create(station=station, vehicle=vehicle, controller="tasc-pwm", form=None,
                           dt_s=0.01, max_time_s=150.0, track=line.track)
scenario = draw_scenario(load_disturbances("standard"), station, vehicle, RunStreams.for_runs(3, 10, 6))[0]
order = launch_order(scenario_arrays(scenario)[0], "tasc-pwm")
assert sorted(order.tolist()) == list(range(6)) and order.tolist() != list(range(6)), order
assert launch_order(scenario_arrays(scenario)[0], "ato").tolist() == list(range(6))
for name in ("standard", "nominal"):  # per-run gradients, and one gradient for all (read-only)
    scenario = draw_scenario(load_disturbances(name), station, vehicle, RunStreams.for_runs(3, 10, 6))[0]
    cpu, cpu_pass, _ = run_kernel(model, scenario, seed=3, first_run=10)
    for order in ("auto", "drawn", "entry-speed"):
        for draws in DRAW_LAYOUTS:
            res, passages = run_kernel_gpu(
                model, scenario, seed=3, first_run=10, order=order, options=KernelOptions(draws=draws)
            )
            assert np.array_equal(res, cpu, equal_nan=True), (name, order, draws)
            assert np.array_equal(passages, cpu_pass, equal_nan=True), (name, order, draws)
print("OK")
"""


def test_the_launch_order_does_not_change_a_run(tmp_path: Path) -> None:
    """The host hands a TASC controller's runs to the threads by entry speed (model.gpu.launch_order,
    a warp's runs then take about as many steps; the others as drawn); each thread still runs its
    own row and run index, so the rows equal the CPU's in either order and with the draws laid out
    in any of the layouts (rows as drawn, rows or columns in launch order; simulator)."""
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1")
    p = subprocess.run(
        [sys.executable, "-c", _ORDER_CHECK],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert p.returncode == 0 and p.stdout.strip().endswith("OK"), p.stderr[-2000:]
