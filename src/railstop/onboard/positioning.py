"""The onboard position-correction device of SPEC §2 as a pure, array-first unit.

SPEC §2: the onboard device keeps a track-circuit DB (ID -> absolute chainage
of the circuit's start), receives (circuit ID, occupancy instant in GNSS time)
from the wayside, and its position module compares the tachometer position
*at the occupancy instant* with the circuit start and corrects the accumulated
error; corrected position and speed go to the train control. This unit:

- keeps a log of (its own GNSS clock time, odometer distance, tachometer
  speed), one sample per call of :meth:`PositioningUnit.log`, over
  ``log_window_s`` (a ring buffer of shape (n, L));
- on a telegram (:meth:`PositioningUnit.handle`): S30 looks the circuit up in
  the DB; finds the odometer reading at the telegram's GNSS time by linear
  interpolation in the log (a telegram time a little past the newest sample,
  possible with clock offsets, is extrapolated with the last speed up to
  ``max_extrapolation_s``); S40 sets the position at that instant to the
  circuit's start: ``corrected(t) = start + odo(t) - odo(t_occ)``;
- rejects (does not correct from) a telegram whose circuit is not in the DB
  or whose time lies outside its log (DESIGN rule 7: no correction is safer
  than a wrong one; the rejection is counted).

Beyond SPEC §2, a **learner** estimates from the history of fixes the
odometer's scale ``a = D_assumed / D_actual`` and the constant part ``d`` of
the delay between the first axle's entry and the time in the telegram
(detection delay plus any constant clock offset). Between two fixes i-1, i
(surveyed starts x, odometer readings o, tachometer speeds v at the telegram
times) the train moved ``x_i - x_{i-1} + d (v_i - v_{i-1}) / a`` true metres
(it was ``d · v / a`` past the start when the odometer was read), so::

    o_i - o_{i-1} = a (x_i - x_{i-1}) + d (v_i - v_{i-1}) + noise

linear in theta = (a, d). A Kalman filter over the fixes of each run (a
recursive least squares with prior ``a ~ N(1, scale_prior)``, ``d ~ N(d0,
delay_prior)``, d0 the nominal detection delay of the line data, 0 when not
given) estimates theta. The noise of one fix is the boundary
uncertainty of its circuit (from the DB: the line data gives it per kind;
``fix_sd_m`` when not given) and the delay spread times the speed. Intervals
in which the wheel-slide / anti-slip protection acted (``wsp_active`` in the
log) are not learned from (the odometer was off by the creep), and an
interval whose innovation exceeds ``gate_sigma`` standard deviations is
rejected as an outlier.

The calibrated position does not simply jump to each fix: the fix
``z = start + d · v_occ / a`` (the position when the odometer was read) is
weighed against the calibrated dead reckoning since the previous fix,
``p = p_prev + (o_i - o_{i-1}) / a``, by their variances (a scalar Kalman
update): once the scale is known, dead reckoning over a few hundred metres
is better than one fix through a jointless circuit's tuned zone. After a
slide or slip the dead reckoning is not trusted (the fix is taken as it is).
Between fixes::

    calibrated(t) = p_i + (odo(t) - o_i) / a

The scale error shows in proportion to the distance since the last fix, the
delay in proportion to the speed at the fix: that is what separates them. At
constant speed ``d`` is not observable (every fix shifts by the same ``d·v``)
and the learner keeps its prior there; speed changes between fixes (leaving
and approaching stations) reveal it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from railstop.config.schema import Positioning, TrackCircuit

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

# Process noise added to the learner per fix (standard deviations): the wheel
# diameter and the delay are constant within a run, a little process noise
# keeps the filter able to follow a slow change (wear, a clock in holdover).
SCALE_PROCESS_SD = 1e-5
DELAY_PROCESS_SD_S = 1e-3
# An interval shorter than this (surveyed metres) carries no scale information worth learning.
MIN_LEARN_DISTANCE_M = 20.0
# Dead-reckoning error the learned scale does not explain (fraction of the distance, standard
# deviation): pulse quantisation, wheel diameter differences between axles, curves.
ODOMETRY_NOISE_FRAC = 1e-3


class FixOutcome(IntEnum):
    ACCEPTED = 0
    UNKNOWN_CIRCUIT = 1  # the ID is not in the track-circuit DB
    STALE = 2  # older than the log window
    FUTURE = 3  # later than the newest log sample + max_extrapolation_s


@dataclass(frozen=True, slots=True, kw_only=True)
class FixReport:
    """What :meth:`PositioningUnit.handle` did with k telegrams (one row each)."""

    run: IntArray
    circuit_id: IntArray
    outcome: IntArray  # FixOutcome
    circuit_start_m: FloatArray  # NaN when unknown
    odometer_at_fix_m: FloatArray  # NaN when rejected
    speed_at_fix_mps: FloatArray
    corrected_jump_m: FloatArray  # SPEC §2 S40 correction: document position before - after (0 if rejected)
    calibrated_jump_m: FloatArray
    learned: BoolArray  # the interval ending at this fix updated the learner
    gated: BoolArray  # the interval was an outlier and was not learned from

    @property
    def accepted(self) -> BoolArray:
        return self.outcome == FixOutcome.ACCEPTED


class PositioningUnit:
    """SPEC §2 onboard position-correction device for n runs (DESIGN rules 1, 2)."""

    def __init__(
        self,
        *,
        circuits: Sequence[TrackCircuit],
        settings: Positioning,
        n: int,
        cycle_s: float,
        start_position_m: FloatArray,
        boundary_sd_m: Sequence[float] | None = None,
        delay_spread_s: float = 0.0,
        nominal_delay_s: float = 0.0,
    ) -> None:
        """``boundary_sd_m``: per circuit (in the order of ``circuits``), the uncertainty of its
        start as a fix; ``delay_spread_s``, ``nominal_delay_s``: the detection delay's spread and
        mean (all line data); the nominal delay is the learner's prior, it learns the actual one."""
        if cycle_s <= 0.0:
            raise ValueError(f"cycle_s must be positive, got {cycle_s}")
        if delay_spread_s < 0.0:
            raise ValueError(f"delay_spread_s must not be negative, got {delay_spread_s}")
        ids = np.array([c.id for c in circuits], dtype=np.int64)
        starts = np.array([c.start_m for c in circuits], dtype=np.float64)
        sds = np.full(ids.size, settings.fix_sd_m) if boundary_sd_m is None else np.asarray(boundary_sd_m)
        if sds.shape != ids.shape or np.any(sds < 0.0):
            raise ValueError("boundary_sd_m needs one non-negative value per circuit")
        order = np.argsort(ids)
        self.db_ids = ids[order]  # SPEC §2 track-circuit DB: ID -> start chainage
        self.db_starts_m = starts[order]
        self.db_sd_m = sds[order].astype(np.float64)
        self.delay_spread_s = float(delay_spread_s)
        self.settings = settings
        self.n = n
        length = int(np.ceil(settings.log_window_s / cycle_s)) + 1
        self.log_t_s = np.full((n, length), -np.inf)
        self.log_odo_m = np.zeros((n, length))
        self.log_v_mps = np.zeros((n, length))
        self.head = -1  # index of the newest sample (common to all runs: every run logs every cycle)
        self.samples = 0
        x0 = np.broadcast_to(np.asarray(start_position_m, dtype=np.float64), (n,)).copy()
        self.odometer_m = np.zeros(n)  # newest odometer reading
        self.speed_mps = np.zeros(n)  # newest tachometer speed
        # The reference of both positions: position ref_x at odometer reading ref_odo.
        self.ref_odo_m = np.zeros(n)
        self.doc_ref_m = x0.copy()
        self.cal_ref_m = x0.copy()
        self.cal_var_m2 = np.full(n, settings.fix_sd_m**2)  # the start is known like a fix
        # Learner: theta = (a, d), covariance P, the previous fix, WSP activity since it.
        # Without learning the calibrated position is the document's: no scale, no delay.
        d0 = float(nominal_delay_s) if settings.learn else 0.0
        self.theta = np.tile(np.array([1.0, d0]), (n, 1))
        p0 = np.diag([(settings.scale_prior_pct * 1e-2) ** 2, settings.delay_prior_s**2])
        self.cov = np.tile(p0, (n, 1, 1))
        self.prev_x_m = np.full(n, np.nan)
        self.prev_odo_m = np.full(n, np.nan)
        self.prev_v_mps = np.full(n, np.nan)
        self.prev_var_m2 = np.full(n, np.nan)
        self.wsp_since_fix = np.zeros(n, dtype=bool)
        self.corrections = np.zeros(n, dtype=np.int64)
        self.rejected = np.zeros(n, dtype=np.int64)
        self.learned = np.zeros(n, dtype=np.int64)
        self.gated = np.zeros(n, dtype=np.int64)

    # ------------------------------------------------------------------ inputs

    def log(
        self,
        *,
        clock_time_s: FloatArray,
        odometer_m: FloatArray,
        speed_mps: FloatArray,
        wsp_active: BoolArray | None = None,
    ) -> None:
        """One cycle's sample of every run: its clock reading, odometer and tachometer speed."""
        length = self.log_t_s.shape[1]
        self.head = (self.head + 1) % length
        self.samples += 1
        self.log_t_s[:, self.head] = clock_time_s
        self.log_odo_m[:, self.head] = odometer_m
        self.log_v_mps[:, self.head] = speed_mps
        self.odometer_m = np.array(odometer_m, dtype=np.float64)
        self.speed_mps = np.array(speed_mps, dtype=np.float64)
        if wsp_active is not None:
            self.wsp_since_fix |= np.asarray(wsp_active, dtype=bool)

    def handle(self, *, run: IntArray, circuit_id: IntArray, gnss_time_s: FloatArray) -> FixReport:
        """Telegrams (circuit ID, GNSS occupancy time) received by runs ``run``; SPEC §2 S30, S40."""
        run = np.asarray(run, dtype=np.int64)
        cid = np.asarray(circuit_id, dtype=np.int64)
        tg = np.asarray(gnss_time_s, dtype=np.float64)
        k = run.size
        out = {
            "outcome": np.zeros(k, dtype=np.int64),
            "start": np.full(k, np.nan),
            "odo": np.full(k, np.nan),
            "v": np.full(k, np.nan),
            "doc_jump": np.zeros(k),
            "cal_jump": np.zeros(k),
            "learned": np.zeros(k, dtype=bool),
            "gated": np.zeros(k, dtype=bool),
        }
        # Telegrams of one run are applied in their order: one per run and pass.
        remaining = np.arange(k)
        while remaining.size:
            _, first = np.unique(run[remaining], return_index=True)
            now = remaining[np.sort(first)]
            self._apply(now, run[now], cid[now], tg[now], out)
            remaining = np.setdiff1d(remaining, now, assume_unique=True)
        return FixReport(
            run=run,
            circuit_id=cid,
            outcome=out["outcome"],
            circuit_start_m=out["start"],
            odometer_at_fix_m=out["odo"],
            speed_at_fix_mps=out["v"],
            corrected_jump_m=out["doc_jump"],
            calibrated_jump_m=out["cal_jump"],
            learned=out["learned"],
            gated=out["gated"],
        )

    # ----------------------------------------------------------------- outputs

    def corrected_m(self) -> FloatArray:
        """SPEC §2 corrected position (document method) at the newest log sample."""
        return self.doc_ref_m + (self.odometer_m - self.ref_odo_m)

    def calibrated_m(self) -> FloatArray:
        """Corrected position with the learned scale and delay (beyond SPEC §2)."""
        return self.cal_ref_m + (self.odometer_m - self.ref_odo_m) / self.scale_estimate

    def corrected_speed_mps(self) -> FloatArray:
        """Tachometer speed with the learned scale."""
        return self.speed_mps / self.scale_estimate

    @property
    def scale_estimate(self) -> FloatArray:
        """Learned odometer scale a = D_assumed / D_actual (1 = no error)."""
        return self.theta[:, 0]

    @property
    def delay_estimate_s(self) -> FloatArray:
        """Learned constant delay d (s) between the entry into a circuit and the telegram's time."""
        return self.theta[:, 1]

    # ---------------------------------------------------------------- internal

    def lookup_start_m(self, circuit_id: IntArray) -> tuple[BoolArray, FloatArray]:
        """SPEC §2 S30: (known, start chainage) of each circuit ID in the track-circuit DB."""
        known, start, _ = self._lookup(circuit_id)
        return known, start

    def _lookup(self, circuit_id: IntArray) -> tuple[BoolArray, FloatArray, FloatArray]:
        cid = np.asarray(circuit_id, dtype=np.int64)
        pos = np.minimum(np.searchsorted(self.db_ids, cid), self.db_ids.size - 1)
        known = self.db_ids[pos] == cid
        return (
            known,
            np.where(known, self.db_starts_m[pos], np.nan),
            np.where(known, self.db_sd_m[pos], np.nan),
        )

    def odometer_at(self, run: IntArray, clock_time_s: FloatArray) -> tuple[IntArray, FloatArray, FloatArray]:
        """(outcome, odometer, tachometer speed) of runs ``run`` at their clock time ``clock_time_s``."""
        length = self.log_t_s.shape[1]
        order = (self.head + 1 + np.arange(length)) % length  # oldest .. newest
        lt = self.log_t_s[run][:, order]
        lo = self.log_odo_m[run][:, order]
        lv = self.log_v_mps[run][:, order]
        t = np.asarray(clock_time_s, dtype=np.float64)
        rows = np.arange(run.size)
        i = np.sum(lt <= t[:, None], axis=1) - 1  # last sample at or before t; -1 = before the log
        i = np.where(np.isfinite(lt[rows, np.maximum(i, 0)]), i, -1)  # slots never written: -inf
        outcome = np.full(run.size, FixOutcome.ACCEPTED, dtype=np.int64)
        odo = np.full(run.size, np.nan)
        v = np.full(run.size, np.nan)
        outcome[i < 0] = FixOutcome.STALE
        newest = i == length - 1
        dt_new = t - lt[:, -1]
        extrap = newest & (dt_new <= self.settings.max_extrapolation_s)
        outcome[newest & ~extrap] = FixOutcome.FUTURE
        odo[extrap] = lo[extrap, -1] + lv[extrap, -1] * dt_new[extrap]
        v[extrap] = lv[extrap, -1]
        inner = (i >= 0) & ~newest
        if inner.any():
            r, a = rows[inner], i[inner]
            t0, t1 = lt[r, a], lt[r, a + 1]
            w = (t[r] - t0) / (t1 - t0)
            odo[r] = lo[r, a] + w * (lo[r, a + 1] - lo[r, a])
            v[r] = lv[r, a] + w * (lv[r, a + 1] - lv[r, a])
        return outcome, odo, v

    def _apply(
        self, sel: IntArray, run: IntArray, cid: IntArray, tg: FloatArray, out: dict[str, np.ndarray]
    ) -> None:
        """One telegram per run (rows ``sel`` of the report)."""
        known, start, sd = self._lookup(cid)  # SPEC §2 S30: absolute position from the DB
        outcome, odo, v = self.odometer_at(run, tg)  # SPEC §2 S30: passing time -> odometer then
        outcome = np.where(known, outcome, FixOutcome.UNKNOWN_CIRCUIT)
        ok = outcome == FixOutcome.ACCEPTED
        out["outcome"][sel] = outcome
        out["start"][sel] = start
        np.add.at(self.rejected, run[~ok], 1)
        if not ok.any():
            return
        r, x, o, vv, s = run[ok], start[ok], odo[ok], v[ok], sel[ok]
        out["odo"][s] = o
        out["v"][s] = vv
        fix_var = sd[ok] ** 2 + (vv * self.delay_spread_s) ** 2

        # SPEC §2 S40: the odometer position at the occupancy instant becomes the circuit start.
        doc_before = self.doc_ref_m[r] + (o - self.ref_odo_m[r])
        # Beyond SPEC §2: calibrated dead reckoning since the last fix, and its variance.
        a0 = self.theta[r, 0]
        moved = o - self.ref_odo_m[r]
        cal_before = self.cal_ref_m[r] + moved / a0
        pred_var = (
            self.cal_var_m2[r]
            + (moved / (a0 * a0)) ** 2 * self.cov[r, 0, 0]
            + (ODOMETRY_NOISE_FRAC * moved / a0) ** 2
        )
        pred_var = np.where(self.wsp_since_fix[r] | (not self.settings.learn), np.inf, pred_var)

        learned, gated = self._learn(r, x, o, vv, fix_var)
        out["learned"][s] = learned
        out["gated"][s] = gated

        a, d = self.theta[r, 0], self.theta[r, 1]
        self.ref_odo_m[r] = o
        self.doc_ref_m[r] = x
        # Beyond SPEC §2: the train was d·v_true past the start when the odometer was read ...
        z = x + d * vv / a
        z_var = fix_var + (vv / a) ** 2 * self.cov[r, 1, 1]
        # ... and that fix is weighed against the dead reckoning (K = 1 after a slide or slip).
        reset = np.isinf(pred_var)
        pv = np.where(reset, 0.0, pred_var)
        gain = np.where(reset, 1.0, pv / (pv + z_var))
        self.cal_ref_m[r] = cal_before + gain * (z - cal_before)
        self.cal_var_m2[r] = np.where(reset, z_var, (1.0 - gain) * pv)
        out["doc_jump"][s] = doc_before - x
        out["cal_jump"][s] = cal_before - self.cal_ref_m[r]
        self.corrections[r] += 1

    def _learn(
        self, r: IntArray, x: FloatArray, o: FloatArray, v: FloatArray, fix_var: FloatArray
    ) -> tuple[BoolArray, BoolArray]:
        """Kalman update of theta = (a, d) with the interval since each run's previous fix."""
        cfg = self.settings
        dx = x - self.prev_x_m[r]
        usable = cfg.learn & np.isfinite(dx) & (dx >= MIN_LEARN_DISTANCE_M) & ~self.wsp_since_fix[r]
        learned = np.zeros(r.size, dtype=bool)
        gated = np.zeros(r.size, dtype=bool)
        if usable.any():
            u = r[usable]
            phi = np.column_stack([dx[usable], v[usable] - self.prev_v_mps[u]])
            y = o[usable] - self.prev_odo_m[u]
            theta = self.theta[u]
            cov = self.cov[u] + np.diag([SCALE_PROCESS_SD**2, DELAY_PROCESS_SD_S**2])
            p_phi = np.einsum("kij,kj->ki", cov, phi)
            # The interval's noise: that of its two fixes.
            s_var = np.einsum("ki,ki->k", phi, p_phi) + fix_var[usable] + self.prev_var_m2[u]
            innov = y - np.einsum("ki,ki->k", phi, theta)
            good = innov * innov <= cfg.gate_sigma**2 * s_var
            gain = p_phi / s_var[:, None]
            new_theta = theta + gain * innov[:, None]
            new_cov = cov - gain[:, :, None] * p_phi[:, None, :]
            self.theta[u] = np.where(good[:, None], new_theta, theta)
            self.cov[u] = np.where(good[:, None, None], new_cov, cov)
            idx = np.flatnonzero(usable)
            learned[idx[good]] = True
            gated[idx[~good]] = True
            np.add.at(self.learned, u[good], 1)
            np.add.at(self.gated, u[~good], 1)
        self.prev_x_m[r] = x
        self.prev_odo_m[r] = o
        self.prev_v_mps[r] = v
        self.prev_var_m2[r] = fix_var
        self.wsp_since_fix[r] = False
        return learned, gated
