"""Compilation of the one model (DESIGN rule 1): numba's ``njit`` with a safe on-disk cache.

Every per-step function of the stop model (physics, brake chain, sensors,
control laws, link decisions) is written once as a scalar function compiled
by numba; the detailed stop and the campaign run the same machine code.

Compiling the whole model takes tens of seconds, so the machine code is
cached on disk and a later process loads it in a fraction of a second.
numba's own cache checks only the timestamp of the file that defines a
function, not of the files it calls into: a change to ``physics/brake.py``
would leave a stale compiled stop model in ``model/run.py``. The cache
folder is therefore named by a hash of *every* compiled module's source,
numba's and Python's versions and the machine: any change gives a fresh
folder, and stale code is never loaded.

The folder is ``$RAILSTOP_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/railstop``
(``~/.cache/railstop``), one subfolder per hash. ``railstop compile``
fills it (``make install`` runs it once).
"""

from __future__ import annotations

import hashlib
import math
import os
import platform
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numba
import numpy as np

from railstop.errors import RailstopError

F = TypeVar("F", bound=Callable[..., Any])

_PACKAGE = Path(__file__).resolve().parent

#: The modules holding compiled code (paths relative to the package). A test
#: checks that every module using :func:`njit` is listed.
JIT_MODULES: tuple[str, ...] = (
    "jit.py",
    "stream_cores.py",
    "physics/brake.py",
    "physics/train.py",
    "sensors/wayside.py",
    "sensors/odometer.py",
    "sensors/gnss_clock.py",
    "sensors/track_circuit.py",
    "onboard/positioning.py",
    "model/fixes.py",
    "nodes/chain_step.py",
    "control/law.py",
    "control/notch.py",
    "control/tasc.py",
    "control/brake_ident.py",
    "control/supervision.py",
    "wayside/tasc_unit.py",
    "onboard/tasc_receiver.py",
    "onboard/ato.py",
    "onboard/speed_supervision.py",
    "onboard/driver.py",
    "model/records.py",
    "model/step.py",
    "model/run.py",
    "model/parts.py",
)


def source_hash() -> str:
    """Hash of the compiled modules' sources and of the toolchain that compiles them."""
    h = hashlib.sha256()
    for part in (numba.__version__, np.__version__, sys.version, platform.machine(), platform.processor()):
        h.update(part.encode())
    for rel in JIT_MODULES:
        h.update(rel.encode())
        h.update((_PACKAGE / rel).read_bytes())
    return h.hexdigest()[:16]


def cache_root() -> Path:
    env = os.environ.get("RAILSTOP_CACHE_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "railstop"


def cache_dir() -> Path:
    return cache_root() / f"numba-{source_hash()}"


def usable_cache_dir() -> Path:
    """:func:`cache_dir`, created if need be; a RailstopError naming it when it cannot be written.
    (numba, given a cache folder it cannot write, silently caches next to the package's sources
    instead: a folder of one's own choosing is never replaced behind one's back.)"""
    target = cache_dir()
    try:
        target.mkdir(parents=True, exist_ok=True)
        probe = target / f".write-probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        where = "RAILSTOP_CACHE_DIR" if os.environ.get("RAILSTOP_CACHE_DIR") else "the cache folder"
        raise RailstopError(
            f"{where}: {target}: cannot write the compiled stop model there ({exc.strerror or exc}); "
            "set RAILSTOP_CACHE_DIR to a folder you may write"
        ) from None
    return target


# numba reads CACHE_DIR when a cached function is decorated, so this must run
# before any module of JIT_MODULES defines its functions (they import this one).
numba.config.CACHE_DIR = str(usable_cache_dir())  # type: ignore[attr-defined]


# ``_nrt`` is a numba target option without a public type stub.
_numba_njit: Any = numba.njit


def as_python() -> bool:
    """True when numba compiles nothing (``NUMBA_DISABLE_JIT=1``): the model then runs as plain
    Python, a stop in about a second and a half, for study without a compile of minutes. The few
    places that build what only compiled code can (an intrinsic, a C callback, records read by
    attribute) build their Python equivalents instead."""
    return bool(getattr(numba.config, "DISABLE_JIT", False))


def njit(fn: F) -> F:
    """Compile ``fn`` in nopython mode, without the GIL, with numpy's error model, cached on disk.

    ``error_model="numpy"``: a division by zero gives inf or NaN as numpy
    does (the model relies on it in the same places the array code did).
    No ``fastmath``: IEEE semantics (NaN and inf tests) are part of the model.
    Use this for functions that allocate arrays; the per-step cores use
    :func:`njit_step`.
    """
    return _numba_njit(cache=True, nogil=True, error_model="numpy")(fn)


def njit_step(fn: F) -> F:
    """:func:`njit` for a function of the per-step path, which allocates nothing.

    It is compiled without numba's reference counting of arrays (NRT): with
    it every call would increment and decrement an atomic counter per array
    argument on entry and exit. Measured on this project's machine: a call
    with 18 array arguments cost 215 ns with reference counting, 1.4 ns
    without; the stop kernel makes several such calls per 10 ms step. A
    function compiled this way cannot create arrays (numba refuses to
    compile it), so nothing can leak or be freed early.
    """
    return _numba_njit(cache=True, nogil=True, error_model="numpy", _nrt=False)(fn)


def njit_inline(fn: F) -> F:
    """:func:`njit_step` for a small function called every step: numba inlines it into its
    callers, so no call passes array descriptors (seven machine words each) through the stack."""
    return _numba_njit(cache=True, nogil=True, error_model="numpy", _nrt=False, inline="always")(fn)


# --------------------------------------------------------------------------
# Scalar maths that both targets compile (issue: one source for the CPU and the GPU).
# The compiled model does its scalar maths through ``math`` (which numba compiles for the CPU and
# numba-cuda for the GPU, to the same LLVM intrinsics on the CPU as numpy's scalar functions);
# numpy's ``rint``, ``ceil`` and ``floor`` have no ``math`` counterpart that keeps a float
# (``math.ceil`` returns an int, undefined for NaN), hence these three.

_TWO52 = 4503599627370496.0  # 2**52: from here on every float64 is an integer


@njit_inline
def rint_1(x: float) -> float:
    """``numpy.rint`` of a scalar: the nearest integer, halves to even; NaN and inf unchanged.

    Adding and then subtracting 2**52 rounds in the current (round-to-nearest-even) mode: the sum
    lies where float64's spacing is exactly 1. Exact, and bit-identical to ``numpy.rint`` for
    every float64, signed zeros included (a test checks it)."""
    if x >= 0.0:
        if x < _TWO52:
            return math.copysign((x + _TWO52) - _TWO52, x)
        return x
    if x > -_TWO52:
        return math.copysign((x - _TWO52) + _TWO52, x)
    return x  # -inf, a large negative integer, or NaN (every comparison false)


@njit_inline
def ceil_1(x: float) -> float:
    """``numpy.ceil`` of a scalar (a float; NaN and inf unchanged, ``ceil(-0.5)`` is -0.0)."""
    r = rint_1(x)
    if r < x:
        r += 1.0
    if r == 0.0:
        return math.copysign(0.0, x)
    return r


@njit_inline
def floor_1(x: float) -> float:
    """``numpy.floor`` of a scalar (a float; NaN and inf unchanged, ``floor(-0.0)`` is -0.0):
    ``-ceil(-x)``, exact for every float64."""
    return -ceil_1(-x)


# --------------------------------------------------------------------------
# Work arrays on the stack (issue 37: the run's state in registers).
#
# An array the kernel receives as an argument may, for all LLVM knows, overlap every other
# argument: a store into one forces every value read from another to be read again, so the
# run's state makes a round trip through memory at every step. An array on the compiled
# function's own stack overlaps nothing, and one indexed only at constant offsets (a record's
# fields, a unit's named slots) is taken apart into registers (LLVM's scalar replacement). The
# same machine arithmetic runs either way: the results are the same to the bit.


def _stack_buffer(builder: Any, nbytes: int) -> Any:
    """``nbytes`` of stack (16-byte aligned) reserved in the function's entry block, as numba's
    ``cgutils.alloca_once`` reserves its temporaries (so a loop does not grow the stack), and set
    to zero where it is taken (so each run starts from zeroed memory, as a fresh array does)."""
    from llvmlite import ir

    with builder.goto_entry_block():
        buf = builder.alloca(ir.ArrayType(ir.IntType(64), max((nbytes + 7) // 8, 1)))
        buf.align = 16
    builder.store(buf.type.pointee(None), buf)
    return buf


def stack_array_value(
    context: Any, builder: Any, arrty: Any, shape: tuple[int, ...], fill: float = 0.0
) -> Any:
    """The LLVM value of a C-contiguous array of numba type ``arrty`` and constant ``shape`` whose
    memory is this function's stack, zeroed, then set to ``fill`` where that is not zero (for the
    intrinsics that build such arrays: ``model.run.state_on_stack``)."""
    from llvmlite import ir
    from numba.core import types

    llty = context.get_data_type(arrty.dtype)
    itemsize = context.get_abi_sizeof(llty)
    count = int(np.prod(shape)) if shape else 1
    data = builder.bitcast(_stack_buffer(builder, count * itemsize), llty.as_pointer())
    if fill != 0.0:
        value = context.get_constant(arrty.dtype, fill)
        for i in range(count):
            builder.store(value, builder.gep(data, [ir.Constant(ir.IntType(64), i)]))
    intp = context.get_value_type(types.intp)
    strides: list[int] = []
    step = itemsize
    for n in reversed(shape):
        strides.insert(0, step)
        step *= n
    ary = context.make_array(arrty)(context, builder)
    context.populate_array(
        ary,
        data=data,
        shape=[ir.Constant(intp, n) for n in shape],
        strides=[ir.Constant(intp, s) for s in strides],
        itemsize=ir.Constant(intp, itemsize),
        meminfo=None,
    )
    return ary._getvalue()
