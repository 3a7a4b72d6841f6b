"""The summary statistics of a campaign: shares within tolerance, the error's moments, overruns
with their Clopper-Pearson bound, emergency brakes by cause, the low-adhesion runs apart and the
manual driver's corrections, all on whole numpy columns."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from railstop.config.platform import LAMP_CODES
from railstop.errors import RailstopError
from railstop.stats.bounds import clopper_pearson_upper

__all__ = ["BANDS_M", "CONFIDENCE", "DEFAULT_TOLERANCE_M", "RESULT_COLUMNS", "summary_stats"]

# Every column of runs.parquet that is a result; all the others are disturbance parameters.
RESULT_COLUMNS: tuple[str, ...] = (
    "run",
    "stop_error_m",
    "stop_time_s",
    "max_jerk_mps3",
    "notch_changes",
    "commands_sent",
    "commands_received",
    "stopped",
    "slid",
    "emergency_brake",
    "emergency_brake_s",
    "brake_delay_identified_s",
    "brake_lag_identified_s",
    "detectors_filled",
    # SPEC §3 manual driving: outcomes of the stop, not disturbances (a driver's first stand, the
    # re-stops after the F / R lamp, the lamp at the end).
    "first_stop_error_m",
    "restops",
    "lamp",
)
# Fixed reference bands of the summary (m), beside the station's own PSD tolerance
# (Station.psd_tolerance_m: SPEC §1 ±0.35 m, SPEC §3 ±0.50 m for manual lines).
BANDS_M: tuple[float, ...] = (0.30, 0.35, 0.50)
# The tolerance of a campaign whose summary.json does not say (written before it was station data).
DEFAULT_TOLERANCE_M = 0.35
CONFIDENCE = 0.95


def summary_stats(
    stop_error_m: Sequence[float] | np.ndarray,
    max_jerk_mps3: Sequence[float] | np.ndarray,
    stop_time_s: Sequence[float] | np.ndarray,
    stopped: Sequence[bool] | np.ndarray,
    slid: Sequence[bool] | np.ndarray,
    *,
    tolerance_m: float,
    emergency_brake: Sequence[int] | np.ndarray | None = None,
    platform_end_m: float | None = None,
    low_adhesion: Sequence[bool] | np.ndarray | None = None,
    manual: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> dict[str, Any]:
    """The summary statistics of one controller's campaign, from its result columns.

    ``tolerance_m``: the station's PSD tolerance (``Station.psd_tolerance_m``).
    Keys: ``runs``; ``tolerance_m``; ``within_tolerance`` and the fixed
    reference bands ``within_0_30``, ``within_0_35``, ``within_0_50`` (fractions
    in [0, 1] of runs that stopped with |error| ≤ the band; a run that did not
    stop is outside every band whatever its error); ``mean_m``, ``std_m``
    (sample standard deviation), ``p99_abs_m``, ``max_abs_m`` of the stop error
    over all runs with a finite error (a run that did not stop contributes its
    error at the time limit); ``overruns`` (runs with error > +tolerance) and
    ``overrun_ci95_upper``, the one-sided 95 % Clopper–Pearson upper bound
    on P(error > +tolerance) (1 when every run overran); ``p99_max_jerk_mps3``;
    ``mean_stop_time_s`` over the runs that stopped; ``not_stopped``, ``slid``
    (counts). Statistics of no values are NaN.

    With ``emergency_brake`` (the cause codes, 0 none; DESIGN rule 10):
    ``emergency_brakes`` (count), ``emergency_brakes_by_cause`` (name -> count)
    and ``silent_misses``, runs outside the tolerance that no emergency brake
    stopped. With ``platform_end_m`` (the platform end beyond the stopping
    point): ``past_platform_end``, runs whose front ended beyond it. With
    ``low_adhesion`` (the runs that met a low-adhesion patch): the overruns
    reported apart, ``low_adhesion_runs``, ``overruns_low_adhesion`` and, over
    the runs that met none, ``overruns_no_low_adhesion`` with its bound
    ``overrun_ci95_upper_no_low_adhesion`` (no stop law answers for a patch
    whose adhesion cannot give the braking the distance left needs).

    With ``manual`` (SPEC §3 driver controllers: the error at the first standstill, the F / R
    corrections and the lamp at the end, per run): ``first_within_0_35`` and ``first_within_0_50``
    (the driver's own stop), ``first_past_platform_end`` (count; with ``platform_end_m``),
    ``restopped`` (share of runs with a correction), ``mean_restops``, ``aligned`` (share that
    ended with OK lit: the PSD may operate) and ``not_aligned`` (count).
    """
    if not (math.isfinite(tolerance_m) and tolerance_m > 0.0):
        raise RailstopError(f"summary_stats: tolerance_m must be a positive number (got {tolerance_m})")
    error = np.asarray(stop_error_m, dtype=np.float64).ravel()
    jerk = np.asarray(max_jerk_mps3, dtype=np.float64).ravel()
    t_stop = np.asarray(stop_time_s, dtype=np.float64).ravel()
    is_stopped = np.asarray(stopped, dtype=bool).ravel()
    has_slid = np.asarray(slid, dtype=bool).ravel()
    n = int(error.size)
    sizes = {
        "max_jerk_mps3": jerk.size,
        "stop_time_s": t_stop.size,
        "stopped": is_stopped.size,
        "slid": has_slid.size,
    }
    for name, size in sizes.items():
        if size != n:
            raise RailstopError(f"summary_stats: {name}: {size} values for {n} stop errors")

    finite = np.isfinite(error)
    abs_error = np.abs(error)
    # NaN compares False: a run without a finite error is outside every band too.
    ok = is_stopped & finite

    def share_within(band: float) -> float:
        return float(np.count_nonzero(ok & (abs_error <= band)) / n) if n else math.nan

    within = {f"within_{band:.2f}".replace(".", "_"): share_within(band) for band in BANDS_M}
    good = error[finite]
    good_abs = abs_error[finite]
    k = int(np.count_nonzero(error > tolerance_m))
    jerk_ok = jerk[np.isfinite(jerk)]
    t_ok = t_stop[is_stopped & np.isfinite(t_stop)]
    return {
        "runs": n,
        "tolerance_m": float(tolerance_m),
        "within_tolerance": share_within(tolerance_m),
        **within,
        "mean_m": float(np.mean(good)) if good.size else math.nan,
        "std_m": float(np.std(good, ddof=1)) if good.size > 1 else (0.0 if good.size else math.nan),
        "p99_abs_m": float(np.percentile(good_abs, 99.0)) if good.size else math.nan,
        "max_abs_m": float(np.max(good_abs)) if good.size else math.nan,
        "overruns": k,
        "overrun_ci95_upper": clopper_pearson_upper(k, n, CONFIDENCE),
        "p99_max_jerk_mps3": float(np.percentile(jerk_ok, 99.0)) if jerk_ok.size else math.nan,
        "mean_stop_time_s": float(np.mean(t_ok)) if t_ok.size else math.nan,
        "not_stopped": int(np.count_nonzero(~is_stopped)),
        "slid": int(np.count_nonzero(has_slid)),
        **_fail_safe_stats(error, ok & (abs_error <= tolerance_m), emergency_brake, platform_end_m),
        **_adhesion_stats(error > tolerance_m, low_adhesion),
        **_manual_stats(manual, n, platform_end_m),
    }


def _manual_stats(
    manual: tuple[np.ndarray, np.ndarray, np.ndarray] | None, n: int, platform_end_m: float | None
) -> dict[str, Any]:
    """SPEC §3: the driver's first stop, the corrections and the alignment (see summary_stats)."""
    if manual is None:
        return {}
    first, restops, lamp = (np.asarray(a).ravel() for a in manual)
    for name, a in (("first_stop_error_m", first), ("restops", restops), ("lamp", lamp)):
        if a.size != n:
            raise RailstopError(f"summary_stats: {name}: {a.size} values for {n} stop errors")
    first_abs = np.abs(np.asarray(first, dtype=np.float64))
    out: dict[str, Any] = {
        "first_within_0_35": float(np.count_nonzero(first_abs <= 0.35) / n) if n else math.nan,
        "first_within_0_50": float(np.count_nonzero(first_abs <= 0.50) / n) if n else math.nan,
        "restopped": float(np.count_nonzero(restops > 0) / n) if n else math.nan,
        "mean_restops": float(np.mean(restops)) if n else math.nan,
        "aligned": float(np.count_nonzero(lamp == LAMP_CODES["OK"]) / n) if n else math.nan,
        "not_aligned": int(np.count_nonzero(lamp != LAMP_CODES["OK"])),
    }
    if platform_end_m is not None:
        out["first_past_platform_end"] = int(
            np.count_nonzero(np.asarray(first, dtype=np.float64) > platform_end_m)
        )
    return out


def _adhesion_stats(overrun: np.ndarray, low_adhesion: Sequence[bool] | np.ndarray | None) -> dict[str, Any]:
    if low_adhesion is None:
        return {}
    patch = np.asarray(low_adhesion, dtype=bool).ravel()
    if patch.size != overrun.size:
        raise RailstopError(
            f"summary_stats: low_adhesion: {patch.size} values for {overrun.size} stop errors"
        )
    dry = int(np.count_nonzero(~patch))
    dry_overruns = int(np.count_nonzero(overrun & ~patch))
    return {
        "low_adhesion_runs": int(np.count_nonzero(patch)),
        "overruns_low_adhesion": int(np.count_nonzero(overrun & patch)),
        "overruns_no_low_adhesion": dry_overruns,
        "overrun_ci95_upper_no_low_adhesion": clopper_pearson_upper(dry_overruns, dry, CONFIDENCE)
        if dry
        else math.nan,
    }


def _fail_safe_stats(
    error: np.ndarray,
    in_tolerance: np.ndarray,
    emergency_brake: Sequence[int] | np.ndarray | None,
    platform_end_m: float | None,
) -> dict[str, Any]:
    # Lazy (start-up): control.supervision loads numba, which a report of stored results never needs.
    from railstop.control.supervision import EB_CAUSES

    out: dict[str, Any] = {}
    if emergency_brake is not None:
        eb = np.asarray(emergency_brake, dtype=np.int64).ravel()
        if eb.size != error.size:
            raise RailstopError(
                f"summary_stats: emergency_brake: {eb.size} values for {error.size} stop errors"
            )
        out["emergency_brakes"] = int(np.count_nonzero(eb))
        out["emergency_brakes_by_cause"] = {
            name: int(np.count_nonzero(eb == code)) for code, name in EB_CAUSES.items() if np.any(eb == code)
        }
        out["silent_misses"] = int(np.count_nonzero(~in_tolerance & (eb == 0)))
    if platform_end_m is not None:
        out["past_platform_end"] = int(np.count_nonzero(error > platform_end_m))
    return out
