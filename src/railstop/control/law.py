"""The interface of an onboard stop-control law: measurements and the law's own state in, a brake demand out.

Researchers compare stop-control algorithms. A law is one function, written
in the subset of Python that numba compiles::

    from railstop.control.law import control_law

    @control_law(name="my-law")
    def my_law(meas, state, params):
        m, p = meas[0], params[0]
        ...
        return demand_mps2

and the stop model (:mod:`railstop.model.step`) calls it like the built-in
onboard ATO (:mod:`railstop.onboard.ato`, written against this interface),
in ``railstop stop``, ``campaign``, ``compare`` and on the line.

Every controller cycle of the train's brake controller, once the train has a
position reference (its first fix), the model fills the measurements record
and calls the law:

- ``meas[0]`` (:data:`MEASUREMENTS_DTYPE`): what the train knows, never the
  truth: the time, its odometric distance to the stopping point, the
  tachometer's speed (both carry the wheel-diameter error and slip), the
  deceleration its line data give at that position and speed (gradient and
  running resistance), the number of position fixes so far (a new fix is a
  new reference), and whether the law has asked for braking yet;
- ``state`` (float64, :data:`LAW_STATE_SIZE` values): the law's own memory,
  zeroed at the start of every run;
- ``params[0]`` (:data:`LAW_PARAMS_DTYPE`): the train's nominal brake data
  (what its data say, not the run's drawn values).

The law returns the train deceleration it asks of the brakes (m/s²). The
train's own brake controller realises it with its notches (minimum hold,
end-phase choice), as for the ATO. Once the law has asked for braking the
traction stays off (the train no longer holds its approach speed).

Safe by construction (SPEC §1: the brake demand goes to the train's brake
controller; the hazard log's HZ-LAW-01): a demand that is not a number
becomes full service, a negative one no braking, one above full service full
service. The law cannot reach the emergency brake or the traction.

**[interpretation]** SPEC §1 names the onboard ATO's inputs (its own
odometry and load estimate) and its weakness, not an interface; this record
is railstop's, chosen so that the ATO needs nothing else.

The model calls the law through a function pointer (numba's first-class
function type), so the compiled stop model is compiled once and serves every
law: a new law costs only its own compilation (a fraction of a second).
"""

from __future__ import annotations

import hashlib
import linecache
import math
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from numba import cfunc, from_dtype, njit, types
from numba.core.errors import NumbaError

from railstop.config.schema import Vehicle
from railstop.controllers import CONTROLLERS, register_law
from railstop.errors import ConfigError
from railstop.jit import as_python, njit_inline

#: The measurements the law gets each cycle (one record; see the module docstring).
MEASUREMENTS_DTYPE = np.dtype(
    [
        ("t_s", np.float64),  # time since the start of the approach
        ("distance_m", np.float64),  # odometric distance to the stopping point (<= 0: at or past it)
        ("speed_mps", np.float64),  # the tachometer's speed
        ("external_mps2", np.float64),  # gradient + resistance at the train by the line data (+: helps)
        ("fixes", np.int64),  # position fixes so far (a transponder, or a track-circuit correction)
        ("braking", np.bool_),  # the law has asked for braking (the traction is off)
    ]
)
#: The train's nominal brake data (one record).
LAW_PARAMS_DTYPE = np.dtype(
    [
        ("full_service_mps2", np.float64),  # the most the law may ask
        ("dead_time_s", np.float64),  # brake dead time ...
        ("time_constant_s", np.float64),  # ... and first-order lag
        ("response_s", np.float64),  # dead time + lag: the brake's equivalent delay
        ("jerk_limit_mps3", np.float64),
        ("cycle_s", np.float64),  # the controller cycle: the law is called this often
    ]
)
#: Values of the law's own state (float64), zeroed at the start of every run.
LAW_STATE_SIZE = 16

_MEAS = types.Array(from_dtype(MEASUREMENTS_DTYPE), 1, "C")
_PARAMS = types.Array(from_dtype(LAW_PARAMS_DTYPE), 1, "C")
#: The law's signature: (measurements, state, params) -> brake demand (m/s²).
LAW_SIGNATURE = types.float64(_MEAS, types.float64[::1], _PARAMS)

POSITIONING = ("transponders", "corrected")
_NAME = re.compile(r"^[a-z][a-z0-9-]{0,39}$")


@dataclass(frozen=True, slots=True)
class ControlLaw:
    """A stop-control law: its controller name, how the train is positioned, the function.

    ``positioning``: ``transponders`` (odometry reset at the station's transponders, as
    ``ato``) or ``corrected`` (SPEC §2 track-circuit corrections, as ``ato-corrected``).
    """

    name: str
    positioning: str
    function: Callable[..., float]
    source: str  # the file it came from ("railstop": built in)
    _compiled: list[Any] = field(default_factory=list, repr=False, compare=False)

    def compiled(self) -> Any:
        """The law as a numba C callback of :data:`LAW_SIGNATURE` (compiled on first use).

        A loaded law is safe by construction (HZ-LAW-01): it is compiled with bounds checks (an
        index outside its state is an error, not a write into the model's memory) and numpy's
        error model (a division by zero gives inf, not an error); any error it raises makes its
        demand NaN, which the model turns into full service. numba cannot catch an error of a C
        callback itself, so the callback wraps the law in ``try``. A built-in law is railstop's
        own code, compiled as it stands (the model's clamp still applies)."""
        if not self._compiled and as_python():
            # The model run as Python (NUMBA_DISABLE_JIT=1, for study): the law as Python too (a C
            # callback is compiled whatever that setting says).
            self._compiled.append(self.function)
        if not self._compiled and self.source == "railstop":
            # A built-in law (the ATO's): railstop's own code, compiled once into the on-disk
            # cache (a guard is a closure, which numba cannot cache: compiling it anew cost every
            # process about a second).
            self._compiled.append(cfunc(LAW_SIGNATURE, cache=True)(self.function))
        if not self._compiled:
            try:
                inner = njit(boundscheck=True, error_model="numpy", nogil=True)(self.function)

                def guarded(meas: Any, state: Any, params: Any) -> float:
                    try:
                        return float(inner(meas, state, params))
                    except Exception:  # any error: the most restrictive demand
                        return np.nan

                self._compiled.append(cfunc(LAW_SIGNATURE)(guarded))
            except Exception as exc:  # numba's typing may raise anything on a user's code
                raise ConfigError(self.source, self.name, f"the law does not compile: {_why(exc)}") from None
        return self._compiled[0]


def _why(exc: BaseException) -> str:
    """One line on why numba refused a law: its own first line, or the error's kind (a field the
    record does not have comes as a KeyError of the field's name)."""
    if isinstance(exc, NumbaError):
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
        return lines[0] if lines else type(exc).__name__
    if isinstance(exc, KeyError):
        return f"no field {exc.args[0]!r} in its records" if exc.args else "KeyError"
    return f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}".rstrip(": ")


def control_law(
    *, name: str, positioning: str = "transponders"
) -> Callable[[Callable[..., float]], ControlLaw]:
    """Declare ``function(meas, state, params) -> demand`` a stop-control law named ``name``."""

    def wrap(function: Callable[..., float]) -> ControlLaw:
        module = getattr(function, "__module__", "")
        origin = (
            "railstop"
            if module.startswith("railstop.")
            else str(getattr(sys.modules.get(module), "__file__", module))
        )
        if not _NAME.match(name):
            raise ConfigError(origin, "name", "a law's name is 1-40 lowercase letters, digits and '-'", name)
        if positioning not in POSITIONING:
            raise ConfigError(origin, f"{name}.positioning", f"one of {', '.join(POSITIONING)}", positioning)
        return ControlLaw(name=name, positioning=positioning, function=function, source=origin)

    return wrap


#: The laws loaded from users' files in this process, by name.
_LOADED: dict[str, ControlLaw] = {}


def loaded_law(name: str) -> ControlLaw | None:
    return _LOADED.get(name)


@dataclass(frozen=True, slots=True)
class LawFile:
    """A law file as a campaign records it: its path, its text and the text's SHA-256. The text
    travels with the campaign to its worker processes (or a Dask cluster's machines, where the
    path may not exist); a resumed campaign must run the same text."""

    path: str
    text: str
    sha256: str

    @classmethod
    def of(cls, path: Path) -> LawFile:
        """Read ``path`` (bad input: :class:`ConfigError` naming it)."""
        path = Path(path)
        if not path.is_file():
            raise ConfigError(str(path), "file", "no such law file")
        if path.suffix != ".py":
            raise ConfigError(str(path), "file", "a law file is a Python file (.py)", path.suffix)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError(str(path), "file", exc.strerror or "cannot be read") from None
        except UnicodeDecodeError as exc:
            raise ConfigError(str(path), "file", f"not UTF-8 text (byte {exc.start})") from None
        return cls(path=str(path), text=text, sha256=hashlib.sha256(text.encode()).hexdigest())

    def load(self) -> list[ControlLaw]:
        """Define and register the file's laws in this process (again: the same laws)."""
        return _load_source(self.text, self.path, self.sha256)

    def manifest(self) -> dict[str, str]:
        return {"file": Path(self.path).name, "sha256": self.sha256}


def load_law_file(path: Path) -> list[ControlLaw]:
    """Run the Python file ``path`` (outside the package) and register every law it defines.

    Bad input (no such file, an error when it runs, no law in it, a name of a built-in
    controller or of another file's law, a law that does not compile) raises
    :class:`ConfigError` naming the file (and the line).
    """
    return LawFile.of(path).load()


def _load_source(text: str, origin: str, digest: str) -> list[ControlLaw]:
    module_name = f"railstop_law_{digest[:16]}"
    module = sys.modules.get(module_name)
    if module is None:
        module = ModuleType(module_name)
        module.__file__ = origin
        # The text under the file's name: numba and tracebacks quote its lines.
        linecache.cache[origin] = (len(text), None, text.splitlines(keepends=True), origin)
        sys.modules[module_name] = module
        try:
            exec(compile(text, origin, "exec"), module.__dict__)
        except ConfigError as exc:
            del sys.modules[module_name]
            raise ConfigError(origin, exc.field, exc.message, exc.value) from None
        except Exception as exc:  # any error in a user's file is bad input, named by its line
            del sys.modules[module_name]
            where = _error_line(exc, origin)
            raise ConfigError(origin, where, f"{type(exc).__name__}: {exc}") from None
    laws = [v for v in vars(module).values() if isinstance(v, ControlLaw)]
    if not laws:
        raise ConfigError(origin, "file", "defines no law (decorate a function with @control_law(name=...))")
    for law in laws:
        if law.name in CONTROLLERS:
            raise ConfigError(origin, "name", "a built-in controller has that name; choose another", law.name)
        other = _LOADED.get(law.name)
        if other is not None and other.function is not law.function:
            raise ConfigError(origin, "name", f"already the name of a law of {other.source}", law.name)
    for law in laws:
        law.compiled()  # compile now: an error names the file before any run starts
        _LOADED[law.name] = law
        register_law(law.name, law.positioning)
    return laws


def _error_line(exc: BaseException, origin: str) -> str:
    """``line N``: the innermost line of ``path`` where ``exc`` was raised (a syntax error's own)."""
    if isinstance(exc, SyntaxError) and exc.lineno:
        return f"line {exc.lineno}"
    tb = exc.__traceback__
    line = "import"
    while tb is not None:
        if tb.tb_frame.f_code.co_filename == origin:
            line = f"line {tb.tb_lineno}"
        tb = tb.tb_next
    return line


def law_params(vehicle: Vehicle, dt_s: float) -> np.ndarray:
    """The law's parameters record (:data:`LAW_PARAMS_DTYPE`) from the vehicle's nominal brake data."""
    brake = vehicle.brake
    lp = np.zeros(1, dtype=LAW_PARAMS_DTYPE)
    lp[0]["full_service_mps2"] = brake.full_service_mps2
    lp[0]["dead_time_s"] = brake.dead_time_s
    lp[0]["time_constant_s"] = brake.time_constant_s
    lp[0]["response_s"] = brake.dead_time_s + brake.time_constant_s
    lp[0]["jerk_limit_mps3"] = brake.jerk_limit_mps3
    lp[0]["cycle_s"] = controller_cycle_steps(vehicle, dt_s) * dt_s
    # The model run as Python (NUMBA_DISABLE_JIT=1): a record array, whose element takes its fields
    # as attributes as a compiled record does.
    return lp.view(np.recarray) if as_python() else lp


def controller_cycle_steps(vehicle: Vehicle, dt_s: float) -> int:
    """The train's brake controller cycle in model steps (at least one): the law runs this often."""
    return max(1, round(vehicle.brake.controller_cycle_s / dt_s))


@njit_inline
def reset_law_1(state: np.ndarray, params: np.ndarray, nominal: np.ndarray) -> None:
    """The start of a run: the law's state zeroed, its parameters record a fresh copy of the
    nominal one (a law that writes into its parameters changes only its own run)."""
    state[:] = 0.0
    q, n = params[0], nominal[0]
    q.full_service_mps2 = n.full_service_mps2
    q.dead_time_s = n.dead_time_s
    q.time_constant_s = n.time_constant_s
    q.response_s = n.response_s
    q.jerk_limit_mps3 = n.jerk_limit_mps3
    q.cycle_s = n.cycle_s


@njit_inline
def safe_demand_1(demand: float, full_service_mps2: float) -> float:
    """HZ-LAW-01: the law's demand within [0, full service]; not a number (or infinite): full service."""
    if not math.isfinite(demand):
        return full_service_mps2 if not demand < 0.0 else 0.0
    return min(max(demand, 0.0), full_service_mps2)
