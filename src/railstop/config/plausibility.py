"""Engineering plausibility of a line with a vehicle: checks the schema cannot make alone.

The schema checks each file on its own (types, ranges, order). A line can pass
it and still be one no train can use; these checks catch that before a stop is
simulated, each as a :class:`~railstop.errors.ConfigError` naming the line
file, the field and its value:

- every platform is at least as long as the train (its doors at the platform's doors);
- every TASC detector, the Doppler radar and the start of the approach lie on
  the line (chainage 0 .. the line's length or the end of its track circuits)
  and after the previous station's stopping point (a zone cannot reach back
  through another station's stop);
- the entry speed of every TASC zone is at most the line's speed limit;
- the medium of every TASC zone is one of the presets of ``railstop/data/media.toml``;
- the zone is long enough: a train entering at the entry speed can stop
  before the stopping point from the first detector, braking at
  ``BRAKE_MARGIN`` of full service after the brake's dead time and build-up,
  on the steepest downhill of the zone.

A disturbance set may draw entries faster than the station's entry speed and
approach gradients steeper than its own: :func:`envelope_note` applies the
same rule at the set's fastest entry and steepest downhill, for the campaign
to say so beside its figures (a note, not an error: studying a station beyond
its design is a use of the tool).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from railstop.config.disturbances import APPROACH_BEFORE_FIRST_DETECTOR_M, Distribution, DisturbanceSet
from railstop.config.loader import line_source, load_line, load_vehicle
from railstop.config.media import MEDIA_FILE, load_media
from railstop.config.schema import Line, Station, Vehicle
from railstop.errors import ConfigError, RailstopError
from railstop.quantities import KMH_PER_MPS

G_MPS2 = 9.80665
# [interpretation] SPEC §1 has the wayside compute the braking the train needs from the first
# detector on; "with margin" is taken as: the stop must be reachable at 80 % of full service,
# the weak end of the standard disturbance set's brake gain (0.8), so that a train with weak
# brakes still has full service in reserve.
BRAKE_MARGIN = 0.8


def _line_end(line: Line) -> float | None:
    ends = [e for e in (line.line.length_m, line.track.end_m) if e is not None]
    return min(ends) if ends else None


def _worst_permille(station: Station, start_m: float, end_m: float) -> float:
    """The steepest downhill (most negative permille, R direction) over [start_m, end_m]; 0 if level."""
    worst = 0.0
    for seg in station.gradient:
        if seg.end_m > start_m and seg.start_m < end_m:
            worst = min(worst, seg.permille)
    return worst


def stopping_distance_m(
    station: Station, vehicle: Vehicle, speed_kmh: float, grade_permille: float | None = None
) -> float:
    """From the first detector at ``speed_kmh``: dead time and build-up at speed, then braking at
    ``BRAKE_MARGIN`` of full service less the zone's steepest downhill (``grade_permille``: this
    one instead) (inf if that cannot stop)."""
    if grade_permille is None:
        grade_permille = _worst_permille(station, station.detector_positions_m()[0], station.stop_point_m)
    return float(_needed_m(vehicle, np.array([speed_kmh]), np.array([grade_permille]))[0])


def _needed_m(
    vehicle: Vehicle, speed_kmh: NDArray[np.float64], grade_permille: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The rule of :func:`stopping_distance_m`, element by element."""
    v = np.asarray(speed_kmh, dtype=np.float64) / KMH_PER_MPS  # as quantities.kmh_to_mps
    brake = vehicle.brake
    decel = BRAKE_MARGIN * brake.full_service_mps2 + G_MPS2 * np.asarray(grade_permille) / 1000.0
    with np.errstate(divide="ignore", invalid="ignore"):
        need = v * (brake.dead_time_s + brake.time_constant_s) + v * v / (2.0 * decel)
    return np.where(decel > 0.0, need, np.inf)


def _extreme(d: Distribution, highest: bool) -> float:
    """The highest (lowest) value ``d`` can draw."""
    if d.fixed is not None:
        return d.fixed
    if d.uniform is not None:
        return d.uniform[1] if highest else d.uniform[0]
    if d.clip is not None:
        return d.clip[1] if highest else d.clip[0]
    if d.choice:
        return max(d.choice) if highest else min(d.choice)
    raise ValueError("a distribution with nothing to draw")


def envelope_note(station: Station, vehicle: Vehicle, dist: DisturbanceSet) -> str | None:
    """The zone-length rule of :func:`plausibility_problems` at ``dist``'s fastest entry and
    steepest downhill in the zone (approach or platform; the station's own where the set draws
    neither): None where the zone is long enough for them, else a one-line note of why stops
    beyond it may end by an overrun guard's emergency brake or outside the tolerance.

    [interpretation] The set's draws are absolute (``entry_speed_kmh = {uniform = [45, 65]}`` at
    every station), while a station's zone is laid out for its own entry speed; a campaign
    beyond that envelope measures the layout as much as the controller, and says so.
    """
    p = dist.params
    own = station.tasc.entry_speed_kmh
    speed = max(_extreme(p["entry_speed_kmh"], True), own) if "entry_speed_kmh" in p else own
    grades = ("approach_gradient_permille", "platform_gradient_permille")
    drawn = [_extreme(p[k], False) for k in grades if k in p]
    first_m = station.detector_positions_m()[0]
    if len(drawn) < len(grades):
        # The zone part the set does not draw keeps the station's own gradient (draw_scenario).
        drawn.append(_worst_permille(station, first_m, station.stop_point_m))
    grade = min(*drawn, 0.0)
    need = stopping_distance_m(station, vehicle, speed, grade)
    first = station.stop_point_m - first_m
    if need <= first:
        return None
    return (
        f"the zone of {station.name!r} is short for the {dist.name!r} set: entries up to {speed:g} km/h "
        f"(the station's entry speed is {own:g}) on downhills to {grade:g} ‰ need {need:.0f} m "
        f"at {BRAKE_MARGIN:.0%} of full service, the first detector is {first:g} m out; stops beyond "
        "the zone's envelope may end by an overrun guard's emergency brake or outside the tolerance"
    )


def beyond_envelope(
    station: Station,
    vehicle: Vehicle,
    entry_speed_kmh: NDArray[np.float64],
    approach_permille: NDArray[np.float64],
    platform_permille: NDArray[np.float64],
) -> NDArray[np.bool_]:
    """Per run (its entry speed and gradients as a campaign's rows hold them: drawn, or the
    station's own mean where the set draws none): whether the zone-length rule needs more than
    the zone has at that run's entry on its steepest downhill (:func:`envelope_note` run by run)."""
    grade = np.minimum(np.minimum(approach_permille, platform_permille), 0.0)
    need = _needed_m(vehicle, entry_speed_kmh, grade)
    return np.asarray(need > station.stop_point_m - station.detector_positions_m()[0])


def plausibility_problems(line: Line, vehicle: Vehicle, source: str) -> list[ConfigError]:
    """Every problem found, in station order (empty: the line is usable with this vehicle)."""
    problems: list[ConfigError] = []
    end = _line_end(line)
    on_line = f"0 .. {end:g} m" if end is not None else "chainage >= 0 m"
    limit = line.line.speed_limit_kmh
    media = sorted(load_media())
    for i, st in enumerate(line.stations):
        where = f"stations[{i}].tasc"
        zone = st.tasc
        if vehicle.length_m > st.platform_length_m:
            # SPEC §1, §5: the train stands at the platform with every door at a platform door.
            problems.append(
                ConfigError(
                    source,
                    f"stations[{i}].platform_length_m",
                    f"shorter than the train {vehicle.name!r} ({vehicle.length_m:g} m): "
                    "its rear doors would open off the platform",
                    st.platform_length_m,
                )
            )
        previous_stop = line.stations[i - 1].stop_point_m if i > 0 else None
        layouts = {"detectors_before_stop_m": zone.detectors_before_stop_m}
        if zone.detectors_only_before_stop_m is not None:  # SPEC §1 claim 6: the variant's too
            layouts["detectors_only_before_stop_m"] = zone.detectors_only_before_stop_m
        placed = [(name, j, d, st.stop_point_m - d) for name, ds in layouts.items() for j, d in enumerate(ds)]
        for name, j, d, x in placed:
            field = f"{where}.{name}[{j}]"
            if x < 0.0 or (end is not None and x > end):
                problems.append(
                    ConfigError(source, field, f"puts the detector at {x:g} m, off the line ({on_line})", d)
                )
            elif previous_stop is not None and x <= previous_stop:
                problems.append(
                    ConfigError(
                        source,
                        field,
                        f"puts the detector at {x:g} m, at or before the stopping point of "
                        f"{line.stations[i - 1].name!r} ({previous_stop:g} m)",
                        d,
                    )
                )
        approach = st.detector_positions_m()[0] - APPROACH_BEFORE_FIRST_DETECTOR_M
        if approach < 0.0 and st.detector_positions_m()[0] >= 0.0:
            problems.append(
                ConfigError(
                    source,
                    f"{where}.detectors_before_stop_m[0]",
                    f"the approach starts {APPROACH_BEFORE_FIRST_DETECTOR_M:g} m before the first detector, "
                    f"at {approach:g} m, off the line ({on_line})",
                    zone.detectors_before_stop_m[0],
                )
            )
        if zone.doppler is not None and end is not None:
            radar = st.stop_point_m + zone.doppler.beyond_stop_m
            if radar > end:
                problems.append(
                    ConfigError(
                        source,
                        f"{where}.doppler.beyond_stop_m",
                        f"puts the radar at {radar:g} m, off the line ({on_line})",
                        zone.doppler.beyond_stop_m,
                    )
                )
        if zone.entry_speed_kmh > limit:
            problems.append(
                ConfigError(
                    source,
                    f"{where}.entry_speed_kmh",
                    f"above the line's speed limit line.speed_limit_kmh = {limit:g} km/h",
                    zone.entry_speed_kmh,
                )
            )
        if zone.medium not in media:
            problems.append(
                ConfigError(
                    source,
                    f"{where}.medium",
                    f"unknown medium; railstop/data/{MEDIA_FILE} has: {', '.join(media)}",
                    zone.medium,
                )
            )
        need = stopping_distance_m(st, vehicle, zone.entry_speed_kmh)
        first = zone.detectors_before_stop_m[0]
        if need > first:
            grade = _worst_permille(st, st.detector_positions_m()[0], st.stop_point_m)
            problems.append(
                ConfigError(
                    source,
                    f"{where}.detectors_before_stop_m[0]",
                    f"the zone of {st.name!r} is too short: from {zone.entry_speed_kmh:g} km/h "
                    f"{vehicle.name!r} needs {need:.0f} m at {BRAKE_MARGIN:.0%} of full service "
                    f"({vehicle.brake.full_service_mps2:g} m/s²) on its steepest downhill ({grade:g} ‰)",
                    first,
                )
            )
    return problems


def load_checked(line: str | Path | None, vehicle: str | Path | None) -> tuple[Line, Vehicle]:
    """Load the line and vehicle files (None: the embedded ones) and check them together.

    Raises the first problem (one line, saying how many more ``railstop check`` lists).
    """
    ln = load_line(line)
    veh = load_vehicle(vehicle)
    problems = plausibility_problems(ln, veh, line_source(line))
    if len(problems) == 1:
        raise problems[0]
    if problems:
        raise RailstopError(f"{problems[0]}; {len(problems) - 1} more: `railstop check` lists them")
    return ln, veh
