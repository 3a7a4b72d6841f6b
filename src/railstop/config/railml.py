"""railML import: the infrastructure of a railML 2.x or 3.x file as a railstop line file.

``railstop import railml FILE`` reads, along the tracks the trains run on (in running order):
the tracks' lengths, gradients, speed sections, main signals, train detection (track circuit
borders, insulated joints, axle counters, wheel detectors), platform edges, stop posts / stopping
places and (railML 2) tunnels. What it could not map, and every value it had to assume, is listed
in a report that is also the head of the written file, so that the engineer sees what to check.

The file is read with lxml (entities not resolved, no network, no DTD), through the same bounded
reader as every data file; every number the mapping uses is checked, and a bad one is one error
naming the file, the element (its tag, id and line in the file) and the value.

How railML maps onto the line file (each an **[interpretation]**: railML describes the
infrastructure, railstop needs one line run in one direction):

- the chosen tracks, laid end to end in the order given, make the line; chainage 0 is the start of
  the first; trains run in increasing ``pos`` (railML 2 ``dir="up"``, railML 3
  ``applicationDirection="normal"``); elements for the other direction only are not mapped;
- railML 2 positions are the tracks' own ``pos`` (not ``absPos``, whose mileage may jump);
  railML 3 positions are ``pos`` / ``intrinsicCoord`` on a net element of the chosen tracks, or a
  ``linearCoordinate`` measure mapped through the net element's associated positioning system;
- SPEC §2 track circuits run between consecutive train detection borders (and the line's ends);
  an insulated joint or an axle counter makes a sharp boundary ("insulated"), any other border a
  tuned zone ("jointless"); a circuit takes the kind of the border at its start;
- a fixed block starts at the first border at or after a main signal (within
  ``SIGNAL_TO_BORDER_M``); the circuits before the first such signal form an entry block;
- a station is a platform edge; its stopping point is the farthest stop post on it in the running
  direction (a full-length train's), else ``DEFAULT_STOP_BEFORE_EDGE_END_M`` before the edge's end;
- the TASC detectors (SPEC §1 wheel sensors) are the non-counting wheel detectors within
  ``TASC_ZONE_MAX_M`` before the stopping point; with fewer than two, railstop lays them out from
  the vehicle's braking (:func:`detector_layout`);
- each gradient goes to the station whose approach it lies on (split at platform ends), so that
  the line's profile is the railML one and each station owns its approach.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from railstop.config.files import read_file_bytes
from railstop.config.plausibility import BRAKE_MARGIN, G_MPS2
from railstop.config.schema import DopplerRadar, Vehicle
from railstop.errors import ConfigError
from railstop.quantities import kmh_to_mps

#: How far after a main signal the border that starts its block may be (a signal stands a few
#: metres before the insulated joint it protects).
SIGNAL_TO_BORDER_M = 50.0
#: Where a platform edge has no stop post: the stopping point this far before the edge's end
#: (as the embedded line: the platform ends 5 m past the stop).
DEFAULT_STOP_BEFORE_EDGE_END_M = 5.0
#: Wheel detectors this far before a stopping point (and after the previous one) are its TASC zone.
TASC_ZONE_MAX_M = 600.0
#: The Doppler radar's range an imported station gets (the schema's default), unless its zone needs more.
RADAR_RANGE_M = float(DopplerRadar.model_fields["range_m"].default)
#: The last TASC detector of a laid-out zone (metres before the stop) and the others as fractions
#: of the first: the spacing of the embedded line's zones (e.g. 330, 230, 140, 60, 6 m).
LAST_DETECTOR_M = 6.0
DETECTOR_FRACTIONS = (1.0, 0.70, 0.42, 0.18)
#: Margin of a laid-out first detector over the stopping distance at ``BRAKE_MARGIN`` of full service.
LAYOUT_MARGIN = 1.15
#: Length of the CBTC segments (SPEC §4) the import divides the line into.
SEGMENT_M = 100.0
#: Two borders closer than this are one (the same joint given twice, e.g. both rails).
SAME_BORDER_M = 0.5
#: Speed of the line where railML gives none (km/h).
DEFAULT_LINE_SPEED_KMH = 80.0
FIRST_CIRCUIT_ID = 101

_NAMESPACE_HOSTS = ("http://www.railml.org/schemas/", "https://www.railml.org/schemas/")
_BORDER_V3 = {"insulatedRailJoint": True, "axleCounter": True}
_WHEEL_V3 = {"wheelDetector", "wheelSensor", "wheelSwitch"}


@dataclass(frozen=True, slots=True)
class Edge:
    """A platform edge along the line: [start_m, end_m], side "L"/"R" or None, its names."""

    ident: str
    start_m: float
    end_m: float
    side: str | None
    name: str | None


@dataclass(slots=True)
class Infrastructure:
    """What a reader found along the chosen tracks, in line chainage (version-independent)."""

    version: str
    length_m: float
    source: str = "(railML)"  # the file, for the messages
    name: str | None = None
    line_speed_kmh: float | None = None
    speeds: list[tuple[float, float, float]] = field(default_factory=list)  # start, end, km/h
    gradients: list[tuple[float, float, float]] = field(default_factory=list)  # start, end, permille
    borders: list[tuple[float, bool, str]] = field(default_factory=list)  # x, sharp, railML id
    signals: list[tuple[float, str, str]] = field(default_factory=list)  # x, id, name
    edges: list[Edge] = field(default_factory=list)
    stops: list[tuple[float, str]] = field(default_factory=list)  # x, id
    wheel_detectors: list[tuple[float, str]] = field(default_factory=list)
    tunnels: list[tuple[float, float, str | None]] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)  # what was not mapped, one sentence each


@dataclass(frozen=True, slots=True)
class Imported:
    """The line file's data (ready for TOML) and the report of the mapping."""

    data: dict[str, Any]
    report: list[str]
    version: str
    circuit_sources: tuple[str, ...] = ()  # the railML element that starts each track circuit


# --------------------------------------------------------------------------------------------
# The XML: bounded, safe parse; elements by local name (railML's namespace changes per version).


def _local(el: Any) -> str:
    tag = el.tag
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def _kids(el: Any, name: str) -> Iterator[Any]:
    return (c for c in el if _local(c) == name)


def _path(el: Any, path: str) -> list[Any]:
    """The elements at ``a/b/c`` (local names) below ``el``."""
    found = [el]
    for step in path.split("/"):
        found = [c for f in found for c in _kids(f, step)]
    return found


def _first(el: Any, path: str) -> Any | None:
    found = _path(el, path)
    return found[0] if found else None


class _Reader:
    """Number and reference checks that name the file, the element and its line."""

    def __init__(self, source: str) -> None:
        self.source = source

    def where(self, el: Any, attr: str | None = None) -> str:
        ident = el.get("id")
        label = f"{_local(el)} {ident!r}" if ident else _local(el)
        at = f" @{attr}" if attr else ""
        return f"{label} (line {el.sourceline}){at}"

    def error(self, el: Any, attr: str | None, message: str, value: object = None) -> ConfigError:
        return ConfigError(self.source, self.where(el, attr), message, value)

    def num(self, el: Any, attr: str, default: float | None = None) -> float:
        raw = el.get(attr)
        if raw is None:
            if default is None:
                raise self.error(el, attr, "missing")
            return default
        try:
            value = float(raw)
        except ValueError:
            raise self.error(el, attr, "not a number", raw) from None
        if not math.isfinite(value):
            raise self.error(el, attr, "not a finite number", raw)
        return value

    def opt_num(self, el: Any, attr: str) -> float | None:
        return None if el.get(attr) is None else self.num(el, attr)


def parse_xml(raw: bytes, source: str) -> Any:
    """The root element of the railML bytes ``raw`` (external entities, DTDs and the network off)."""
    from lxml import etree

    parser = etree.XMLParser(
        resolve_entities=False,
        no_network=True,
        load_dtd=False,
        dtd_validation=False,
        huge_tree=False,
        remove_comments=True,
        remove_pis=True,
    )
    # railML files declare no DTD: a DOCTYPE (entity declarations: an external file read in, or
    # entities expanding a billion times) is refused as a class, before and after the parse (the
    # parse's own check also sees a DOCTYPE in another encoding).
    doctype = ConfigError(
        source, "(xml)", "a DOCTYPE declaration (DTD or entities): railML files have none; refused for safety"
    )
    head = raw[:131072]
    if any(
        "<!DOCTYPE".encode(enc) in head
        for enc in ("utf-8", "utf-16-le", "utf-16-be", "utf-32-le", "utf-32-be")
    ):
        raise doctype
    try:
        root = etree.fromstring(raw, parser)
    except etree.XMLSyntaxError as exc:
        raise ConfigError(source, "(xml syntax)", str(exc).splitlines()[0]) from None
    if root is None:
        raise ConfigError(source, "(xml syntax)", "no root element")
    if root.getroottree().docinfo.doctype:
        raise doctype
    return root


def railml_version(root: Any, source: str) -> str:
    """ "2.x" or "3.x" (from the root element and its namespace); a ConfigError for any other XML."""
    ns = root.tag[1:].split("}", 1)[0] if isinstance(root.tag, str) and root.tag.startswith("{") else ""
    name = _local(root)
    if name not in ("railml", "railML") or not ns.startswith(_NAMESPACE_HOSTS):
        raise ConfigError(
            source,
            "(root element)",
            "not a railML file: the root must be railml (2.x) or railML (3.x) in a railml.org namespace",
            f"{{{ns}}}{name}" if ns else name,
        )
    declared = root.get("version") or ns.rstrip("/").rsplit("/", 1)[-1]
    major = "3" if name == "railML" or declared.startswith("3") else "2"
    return f"{major}.x ({declared})" if declared else f"{major}.x"


def _count(n: int, noun: str, plural: str | None = None) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {plural or noun + 's'}"


def _choose(tracks: list[Any], wanted: list[str], source: str) -> list[Any]:
    by_id = {t.get("id"): t for t in tracks if t.get("id")}
    if wanted:
        missing = [w for w in wanted if w not in by_id]
        if missing:
            raise ConfigError(
                source,
                "--track",
                f"no such track; the file has: {', '.join(sorted(by_id)) or '(none)'}",
                missing[0],
            )
        return [by_id[w] for w in wanted]
    if len(tracks) == 1:
        return tracks
    if not tracks:
        raise ConfigError(source, "tracks", "the file has no tracks")
    names = ", ".join(sorted(by_id))
    raise ConfigError(
        source,
        "--track",
        f"the file has {len(tracks)} tracks ({names}): name the ones the trains run "
        "on, in running order, with --track",
    )


def _forward(direction: str | None) -> bool:
    """An element for the trains' direction (increasing pos): railML 2 dir, railML 3
    applicationDirection."""
    return direction not in ("down", "reverse")


def _edge_side(value: str | None) -> str | None:
    return {"left": "L", "right": "R"}.get((value or "").lower())


def _stretches(changes: list[tuple[float, float]], end: float) -> list[tuple[float, float, float]]:
    """Changes (x, value), each holding to the next (the last to ``end``), as stretches; at the same
    x the most restrictive (lowest) value holds."""
    changes = sorted(changes)
    at: dict[float, float] = {}
    for x, v in changes:
        at[x] = min(v, at.get(x, v))
    xs = sorted(at)
    out = []
    for i, x in enumerate(xs):
        stop = xs[i + 1] if i + 1 < len(xs) else end
        if stop > x:
            out.append((x, stop, at[x]))
    return out


# --------------------------------------------------------------------------------------------
# railML 2.x: everything hangs on the track; positions are the track's own pos.


def read_v2(root: Any, wanted: list[str], source: str, version: str) -> Infrastructure:
    rd = _Reader(source)
    infra = _first(root, "infrastructure")
    if infra is None:
        raise ConfigError(source, "infrastructure", "missing: the file describes no infrastructure")
    tracks = _choose(_path(infra, "tracks/track"), wanted, source)
    ocp = {o.get("id"): o.get("name") for o in _path(infra, "operationControlPoints/ocp")}
    out = Infrastructure(version=version, length_m=0.0, source=source)
    speed_changes: list[tuple[float, float]] = []
    gradient_changes: list[tuple[float, float]] = []
    offset = 0.0
    for tr in tracks:
        begin = _first(tr, "trackTopology/trackBegin")
        end = _first(tr, "trackTopology/trackEnd")
        if begin is None or end is None:
            raise rd.error(tr, None, "a track needs trackTopology/trackBegin and trackEnd")
        b, e = rd.num(begin, "pos", 0.0), rd.num(end, "pos")
        if e <= b:
            raise rd.error(end, "pos", f"the track must end after its begin ({b:g} m)", e)

        def at(el: Any, b: float = b, e: float = e, off: float = offset) -> float:
            p = rd.num(el, "pos")
            if p < b - 1e-6 or p > e + 1e-6:
                raise rd.error(el, "pos", f"outside its track ({b:g} .. {e:g} m)", p)
            return off + p - b

        els = _first(tr, "trackElements")
        ocs = _first(tr, "ocsElements")
        for g in _path(els, "gradientChanges/gradientChange") if els is not None else []:
            gradient_changes.append((at(g), rd.num(g, "slope")))
        for s in _path(els, "speedChanges/speedChange") if els is not None else []:
            if not _forward(s.get("dir")):
                out.skipped.append(f"speedChange {s.get('id')!r}: for the other direction")
                continue
            try:
                speed_changes.append((at(s), rd.num(s, "vMax")))
            except ConfigError:
                if s.get("vMax") is None or s.get("pos") is None:
                    raise
                out.skipped.append(f"speedChange {s.get('id')!r}: vMax {s.get('vMax')!r} is not a speed")
        for pe in _path(els, "platformEdges/platformEdge") if els is not None else []:
            start = at(pe)
            length = rd.num(pe, "length")
            if length <= 0.0:
                raise rd.error(pe, "length", "must be positive", length)
            name = ocp.get(pe.get("ocpRef")) or pe.get("name")
            out.edges.append(
                Edge(pe.get("id") or "?", start, start + length, _edge_side(pe.get("side")), name)
            )
        for t in _path(els, "tunnels/tunnel") if els is not None else []:
            start = at(t)
            out.tunnels.append((start, start + rd.num(t, "length"), t.get("name")))
        for sig in _path(ocs, "signals/signal") if ocs is not None else []:
            kind = sig.get("type") or "main"
            if kind not in ("main", "combined") or not _forward(sig.get("dir")):
                why = "for the other direction" if not _forward(sig.get("dir")) else f"type {kind!r}"
                out.skipped.append(f"signal {sig.get('id')!r}: {why}, not a block signal")
                continue
            out.signals.append((at(sig), sig.get("id") or "?", sig.get("name") or sig.get("id") or "?"))
        tde = _first(ocs, "trainDetectionElements") if ocs is not None else None
        for tcb in _kids(tde, "trackCircuitBorder") if tde is not None else []:
            sharp = (tcb.get("insulatedRail") or "none") != "none"
            out.borders.append((at(tcb), sharp, tcb.get("id") or "?"))
        for det in _kids(tde, "trainDetector") if tde is not None else []:
            if (det.get("axleCounting") or "false") == "true":
                out.borders.append((at(det), True, det.get("id") or "?"))
            else:
                out.wheel_detectors.append((at(det), det.get("id") or "?"))
        for sp in _path(ocs, "stopPosts/stopPost") if ocs is not None else []:
            if not _forward(sp.get("dir")):
                out.skipped.append(f"stopPost {sp.get('id')!r}: for the other direction")
                continue
            out.stops.append((at(sp), sp.get("id") or "?"))
        offset += e - b
    out.length_m = offset
    out.speeds = _stretches(speed_changes, offset)
    out.gradients = _stretches(gradient_changes, offset)
    if gradient_changes and min(x for x, _ in gradient_changes) > 0.0:
        out.skipped.append(
            f"gradient before the first gradientChange ({min(x for x, _ in gradient_changes):g} m): "
            "taken as level"
        )
    return out


# --------------------------------------------------------------------------------------------
# railML 3.x: a topology of net elements; functional infrastructure located on them.


class _Chain:
    """The chosen tracks' net elements end to end: locations in line chainage."""

    def __init__(self, rd: _Reader, topology: Any) -> None:
        self.rd = rd
        self.lengths: dict[str, float] = {}
        self.measures: dict[str, tuple[float, float]] = {}  # measure at intrinsic 0 and 1
        for ne in _path(topology, "netElements/netElement") if topology is not None else []:
            ident = ne.get("id")
            if ident is None:
                continue
            if ne.get("length") is not None:
                self.lengths[ident] = rd.num(ne, "length")
            ends: dict[float, float] = {}
            for ic in _path(ne, "associatedPositioningSystem/intrinsicCoordinate"):
                lc = _first(ic, "linearCoordinate")
                if lc is not None and ic.get("intrinsicCoord") is not None and lc.get("measure") is not None:
                    ends[rd.num(ic, "intrinsicCoord")] = rd.num(lc, "measure")
            if 0.0 in ends and 1.0 in ends and ends[1.0] != ends[0.0]:
                self.measures[ident] = (ends[0.0], ends[1.0])
        self.parts: dict[str, tuple[float, float, float]] = {}  # ne -> (offset, posBegin, posEnd)
        self.length = 0.0

    def add_track(self, track: Any) -> None:
        rd = self.rd
        assoc = _path(track, "linearLocation/associatedNetElement")
        if not assoc:
            raise rd.error(track, None, "a track needs a linearLocation with its net elements")
        assoc.sort(key=lambda a: rd.num(a, "sequence", 0.0))
        # A track of one net element may give the length its net element lacks (its physical
        # <length>): the element's length is then the track's.
        own = next((x for x in _kids(track, "length") if x.get("type") in (None, "physical")), None)
        for a in assoc:
            ref = a.get("netElementRef")
            if ref is None:
                raise rd.error(a, "netElementRef", "missing")
            if ref not in self.lengths and own is not None and len(assoc) == 1:
                self.lengths[ref] = rd.num(own, "value")
            length = self.lengths.get(ref)
            pb = rd.num(a, "posBegin", 0.0)
            pe = rd.opt_num(a, "posEnd")
            if pe is None:
                if length is None:
                    raise rd.error(a, "posEnd", f"missing, and net element {ref!r} has no length")
                pe = length
            if pe <= pb:
                raise rd.error(a, "posEnd", f"must be after posBegin ({pb:g} m)", pe)
            if ref in self.parts:
                raise rd.error(a, "netElementRef", "this net element is already on the line", ref)
            self.parts[ref] = (self.length, pb, pe)
            self.length += pe - pb

    def _x(self, el: Any, ref: str, pos: float) -> float:
        off, pb, pe = self.parts[ref]
        if pos < pb - 1e-6 or pos > pe + 1e-6:
            raise self.rd.error(
                el, "pos", f"outside the part of {ref!r} on the line ({pb:g} .. {pe:g} m)", pos
            )
        return off + pos - pb

    def _pos(self, el: Any, ref: str, pos_attr: str, coord_attr: str, lc: Any | None) -> float | None:
        """The metres along ``ref`` of a location element (pos, intrinsic coordinate or measure)."""
        rd = self.rd
        if el.get(pos_attr) is not None:
            return rd.num(el, pos_attr)
        length = self.lengths.get(ref)
        if el.get(coord_attr) is not None and length is not None:
            return rd.num(el, coord_attr) * length
        if lc is not None and lc.get("measure") is not None and ref in self.measures and length is not None:
            m0, m1 = self.measures[ref]
            return (rd.num(lc, "measure") - m0) / (m1 - m0) * length
        return None

    def spot(self, owner: Any) -> tuple[float | None, bool]:
        """(chainage or None when not on the chosen tracks, forward) of ``owner``'s spotLocation."""
        for sl in _kids(owner, "spotLocation"):
            ref = sl.get("netElementRef")
            if ref not in self.parts:
                continue
            pos = self._pos(sl, ref, "pos", "intrinsicCoord", _first(sl, "linearCoordinate"))
            if pos is None:
                raise self.rd.error(
                    sl, None, "a location needs pos, intrinsicCoord or a linearCoordinate measure"
                )
            return self._x(sl, ref, pos), _forward(sl.get("applicationDirection"))
        return None, True

    def stretch(self, owner: Any) -> tuple[float, float, bool, str | None] | None:
        """(start, end, forward, lateral side) of ``owner``'s linearLocation on the chosen tracks."""
        xs: list[float] = []
        forward, side = True, None
        for ll in _kids(owner, "linearLocation"):
            forward = forward and _forward(ll.get("applicationDirection"))
            for a in _kids(ll, "associatedNetElement"):
                ref = a.get("netElementRef")
                if ref not in self.parts:
                    continue
                lcb, lce = _first(a, "linearCoordinateBegin"), _first(a, "linearCoordinateEnd")
                for attr, coord, lc in (
                    ("posBegin", "intrinsicCoordBegin", lcb),
                    ("posEnd", "intrinsicCoordEnd", lce),
                ):
                    pos = self._pos(a, ref, attr, coord, lc)
                    if pos is None:
                        raise self.rd.error(
                            a, attr, "needs posBegin/posEnd, intrinsic coordinates or measures"
                        )
                    xs.append(self._x(a, ref, pos))
                if lcb is not None and side is None:
                    side = lcb.get("lateralSide")
        if len(xs) < 2 or max(xs) <= min(xs):
            return None
        return min(xs), max(xs), forward, side


def _name_v3(el: Any) -> str | None:
    names = list(_kids(el, "name"))
    for n in names:
        if (n.get("language") or "").lower().startswith("en") and n.get("name"):
            return str(n.get("name"))
    return next((str(n.get("name")) for n in names if n.get("name")), None)


def read_v3(root: Any, wanted: list[str], source: str, version: str) -> Infrastructure:
    rd = _Reader(source)
    infra = _first(root, "infrastructure")
    fi = _first(infra, "functionalInfrastructure") if infra is not None else None
    if fi is None:
        raise ConfigError(source, "infrastructure", "missing: the file has no functionalInfrastructure")
    chain = _Chain(rd, _first(infra, "topology"))
    for tr in _choose(_path(fi, "tracks/track"), wanted, source):
        chain.add_track(tr)
    out = Infrastructure(version=version, length_m=chain.length, source=source)
    lines = _path(fi, "lines/line")
    if lines:
        out.name = _name_v3(lines[0])
        perf = _first(lines[0], "linePerformance")
        if perf is not None:
            out.line_speed_kmh = rd.opt_num(perf, "maxSpeed")
    if out.line_speed_kmh is None:
        # railML 3 speed sections are restrictions over stretches, not a profile of the whole line:
        # without the line's own speed they cannot give it.
        out.line_speed_kmh = DEFAULT_LINE_SPEED_KMH
        out.skipped.append(
            f"no linePerformance maxSpeed: the line's speed taken as {DEFAULT_LINE_SPEED_KMH:g} km/h"
        )
    off_line = 0
    for sec in _path(fi, "speeds/speedSection"):
        st = chain.stretch(sec)
        if st is None:
            off_line += 1
        elif not st[2]:
            out.skipped.append(f"speedSection {sec.get('id')!r}: for the other direction")
        else:
            out.speeds.append((st[0], st[1], rd.num(sec, "maxSpeed")))
            if sec.get("isTemporary") == "true":
                out.skipped.append(
                    f"speedSection {sec.get('id')!r}: temporary, mapped as permanent (the more "
                    "restrictive reading; remove it from the line file if it is not in force)"
                )
    for gc in _path(infra, "geometry/gradientCurves/gradientCurve"):
        if (gc.get("curveType") or "straight") != "straight":
            out.skipped.append(
                f"gradientCurve {gc.get('id')!r}: a vertical curve ({gc.get('curveType')}), "
                "the straight gradients either side are used"
            )
            continue
        st = chain.stretch(gc)
        if st is None:
            x, _ = chain.spot(gc)
            if x is not None and gc.get("length") is not None:
                st = (x, x + rd.num(gc, "length"), True, None)
        if st is None:
            off_line += 1
            continue
        out.gradients.append((st[0], st[1], rd.num(gc, "gradient")))
    owner_of_edge: dict[str, str] = {}
    for op in _path(fi, "operationalPoints/operationalPoint"):
        name = _name_v3(op)
        if name is None:
            continue
        for ref in _path(op, "opEquipment/ownsPlatform"):
            owner_of_edge[ref.get("ref")] = name
    platforms = _path(fi, "platforms/platform") + _path(fi, "platformEdges/platformEdge")
    for plf in platforms:  # a platform names its edges' station
        for ref in _kids(plf, "ownsPlatformEdge"):
            if plf.get("id") in owner_of_edge:
                owner_of_edge[ref.get("ref")] = owner_of_edge[plf.get("id")]
    for plf in platforms:
        st = chain.stretch(plf)
        if st is None:
            if _first(plf, "linearLocation") is not None:
                off_line += 1
            continue
        name = owner_of_edge.get(plf.get("id")) or _name_v3(plf)
        out.edges.append(Edge(plf.get("id") or "?", st[0], st[1], _edge_side(st[3]), name))
    for sig in _path(fi, "signalsIS/signalIS"):
        x, fwd = chain.spot(sig)
        if x is None:
            off_line += 1
        elif _first(sig, "isTrainMovementSignal") is None:
            out.skipped.append(f"signalIS {sig.get('id')!r}: not a train movement signal")
        elif not fwd:
            out.skipped.append(f"signalIS {sig.get('id')!r}: for the other direction")
        else:
            out.signals.append((x, sig.get("id") or "?", _name_v3(sig) or sig.get("id") or "?"))
    for tde in _path(fi, "trainDetectionElements/trainDetectionElement"):
        x, _ = chain.spot(tde)
        if x is None:
            off_line += 1
            continue
        kind = tde.get("type") or ""
        if kind in _WHEEL_V3:
            out.wheel_detectors.append((x, tde.get("id") or "?"))
        else:
            # [interpretation] any other detection element bounds a detection section: insulated
            # joints and axle counters sharply, the rest (track circuit ends, tuning units) as a zone.
            out.borders.append((x, _BORDER_V3.get(kind, False), tde.get("id") or "?"))
    for sp in _path(fi, "stoppingPlaces/stoppingPlace"):
        x, fwd = chain.spot(sp)
        if x is None:
            off_line += 1
        elif not fwd:
            out.skipped.append(f"stoppingPlace {sp.get('id')!r}: for the other direction")
        else:
            out.stops.append((x, sp.get("id") or "?"))
    if off_line:
        out.skipped.append(f"{off_line} located element(s) not on the chosen tracks")
    return out


# --------------------------------------------------------------------------------------------
# The line file from what was found.


def detector_layout(
    vehicle: Vehicle, entry_speed_kmh: float, steepest_permille: float, source: str = "(railML)"
) -> list[float]:
    """TASC detectors (metres before the stop, farthest first) where railML gives none: the first
    ``LAYOUT_MARGIN`` beyond the stopping distance at ``BRAKE_MARGIN`` of full service on the
    zone's steepest downhill (the plausibility check's rule), the others at the embedded line's
    fractions of it, the last ``LAST_DETECTOR_M`` before the stop. [interpretation]"""
    v = kmh_to_mps(entry_speed_kmh)
    brake = vehicle.brake
    decel = BRAKE_MARGIN * brake.full_service_mps2 + G_MPS2 * min(steepest_permille, 0.0) / 1000.0
    if decel <= 0.0:
        raise ConfigError(
            source,
            "gradient",
            f"a {steepest_permille:g} ‰ downhill: "
            f"{vehicle.name!r} cannot stop on it at {BRAKE_MARGIN:.0%} of full service",
        )
    need = v * (brake.dead_time_s + brake.time_constant_s) + v * v / (2.0 * decel)
    first = 5.0 * math.ceil(need * LAYOUT_MARGIN / 5.0)
    return [round(first * f / 5.0) * 5.0 for f in DETECTOR_FRACTIONS] + [LAST_DETECTOR_M]


def _steepest(gradients: Iterable[tuple[float, float, float]], start: float, end: float) -> float:
    return min((g for a, b, g in gradients if b > start and a < end), default=0.0)


def _circuits(inf: Infrastructure, report: list[str]) -> tuple[list[dict[str, Any]], list[str]]:
    """SPEC §2 track circuits between the borders, and the railML id at each circuit's start."""
    borders = sorted(b for b in inf.borders if 0.0 < b[0] < inf.length_m)
    merged: list[tuple[float, bool, str]] = []
    for x, sharp, ident in borders:
        if merged and x - merged[-1][0] < SAME_BORDER_M:
            px, psharp, pid = merged[-1]
            merged[-1] = (px, psharp or sharp, pid)
        else:
            merged.append((x, sharp, ident))
    starts = [(0.0, False, "(line start)"), *merged]
    circuits = []
    for i, (x, sharp, _) in enumerate(starts):
        end = starts[i + 1][0] if i + 1 < len(starts) else inf.length_m
        circuits.append(
            {
                "id": FIRST_CIRCUIT_ID + i,
                "start_m": x,
                "end_m": end,
                "kind": "insulated" if sharp else "jointless",
            }
        )
    if not inf.borders:
        report.append(
            "no train detection borders: the whole line is one track circuit (SPEC §2 "
            "position correction has one fix; add borders for a real layout)"
        )
    else:
        report.append(
            f"{len(circuits)} track circuits ({FIRST_CIRCUIT_ID}..{FIRST_CIRCUIT_ID + len(circuits) - 1}) "
            f"from {len(borders)} train detection borders"
        )
    return circuits, [s[2] for s in starts]


def _blocks(inf: Infrastructure, circuits: list[dict[str, Any]], report: list[str]) -> dict[str, Any] | None:
    """Fixed blocks: each forward main signal starts one at the first border within reach."""
    starts = [c["start_m"] for c in circuits]
    first_circuit: dict[int, tuple[str, str]] = {}
    for x, ident, name in sorted(inf.signals):
        k = next((i for i, s in enumerate(starts) if x - 1e-6 <= s <= x + SIGNAL_TO_BORDER_M), None)
        if k is None or k in first_circuit:
            why = (
                "another signal starts that block"
                if k is not None
                else (f"no track circuit border within {SIGNAL_TO_BORDER_M:g} m after it")
            )
            inf.skipped.append(f"signal {ident!r} at {x:.1f} m: {why}")
            continue
        first_circuit[k] = (ident, name)
    if not first_circuit:
        report.append("no block signals mapped: no fixed-block signalling (a `line run` needs it)")
        return None
    ks = sorted(first_circuit)
    if ks[0] != 0:
        ks.insert(0, 0)
        first_circuit[0] = ("(entry)", "ENTRY")
        report.append("an entry block with signal ENTRY covers the circuits before the first main signal")
    used: set[str] = set()
    blocks = []
    for n, k in enumerate(ks):
        end = ks[n + 1] if n + 1 < len(ks) else len(circuits)
        name = first_circuit[k][1]
        if len(name) > 16 or name in used:
            name = f"S{n + 1:02d}"
        used.add(name)
        blocks.append({"id": f"B{n + 1:02d}", "circuits": [c["id"] for c in circuits[k:end]], "signal": name})
    report.append(f"{len(blocks)} fixed blocks from {len(inf.signals)} main signals")
    return {"blocks": blocks}


def _speed_limits(inf: Infrastructure, line_kmh: float) -> list[dict[str, Any]]:
    """Stretches below the line's own speed, the lowest section where sections overlap."""
    cuts = sorted({0.0, inf.length_m, *(a for a, _, _ in inf.speeds), *(b for _, b, _ in inf.speeds)})
    out: list[dict[str, Any]] = []
    for a, b in zip(cuts, cuts[1:], strict=False):
        if not 0.0 <= a < b <= inf.length_m:
            continue
        v = min((s for sa, sb, s in inf.speeds if sa < b and sb > a), default=line_kmh)
        if v >= line_kmh:
            continue
        if out and out[-1]["end_m"] == a and out[-1]["limit_kmh"] == v:
            out[-1]["end_m"] = b
        else:
            out.append({"start_m": a, "end_m": b, "limit_kmh": v, "reason": "railML speed section"})
    return out


def _limit_at(limits: list[dict[str, Any]], x: float, line_kmh: float) -> float:
    return min((s["limit_kmh"] for s in limits if s["start_m"] <= x < s["end_m"]), default=line_kmh)


def _stations(
    inf: Infrastructure,
    vehicle: Vehicle,
    entry_kmh: float,
    limits: list[dict[str, Any]],
    line_kmh: float,
    report: list[str],
) -> list[dict[str, Any]]:
    found_at: list[tuple[dict[str, Any], str]] = []  # each station and where its stop comes from
    names: set[str] = set()
    for edge in sorted(inf.edges, key=lambda e: e.end_m):
        on_edge = [(x, i) for x, i in inf.stops if edge.start_m <= x <= edge.end_m + 1e-6]
        if on_edge:
            stop, stop_id = max(on_edge)
            where = f"stop post {stop_id!r}"
            for _, other in sorted(on_edge)[:-1]:
                inf.skipped.append(
                    f"stop post {other!r}: a nearer stop on the edge of {stop_id!r} "
                    "(a shorter train's); the farthest is the station's stop"
                )
        else:
            stop = edge.end_m - DEFAULT_STOP_BEFORE_EDGE_END_M
            where = f"no stop post on the edge: {DEFAULT_STOP_BEFORE_EDGE_END_M:g} m before its end"
        name = (edge.name or edge.ident)[:64]
        while name in names:
            name = f"{name[:60]} {edge.ident}"[:64]
        names.add(name)
        side = edge.side
        if side is None:
            side = "R"
            inf.skipped.append(f"platform edge {edge.ident!r}: side not given, R (right) assumed")
        station = {
            "name": name,
            "stop_point_m": round(stop, 3),
            "platform_length_m": round(edge.end_m - edge.start_m, 3),
            "platform_side": side,
            "platform_end_m": round(edge.end_m, 3),
        }
        found_at.append((station, where))
    found_at.sort(key=lambda sw: sw[0]["stop_point_m"])
    previous = 0.0
    for st, where in found_at:
        stop = st["stop_point_m"]
        detectors = sorted(
            (
                round(stop - x, 3)
                for x, _ in inf.wheel_detectors
                if previous < x < stop and stop - x <= TASC_ZONE_MAX_M
            ),
            reverse=True,
        )
        speed = min(entry_kmh, _limit_at(limits, max(stop - 200.0, 0.0), line_kmh))
        if len(detectors) >= 2:
            how = f"{len(detectors)} wheel detectors from the file"
        else:
            found = len(detectors)
            steep = _steepest(inf.gradients, max(stop - TASC_ZONE_MAX_M, 0.0), stop)
            detectors = detector_layout(vehicle, speed, steep, inf.source)
            how = (
                f"detectors laid out by railstop for {speed:g} km/h "
                f"(the file has {found} wheel detectors before it)"
            )
        st["tasc"] = {
            "entry_speed_kmh": speed,
            "detectors_before_stop_m": detectors,
            # The radar 10 m beyond the stop must see the whole zone (TascZone's rule).
            "doppler": {
                "beyond_stop_m": 10.0,
                "sample_period_s": 0.01,
                "range_m": max(RADAR_RANGE_M, math.ceil(10.0 + detectors[0])),
            },
        }
        report.append(
            f"station {st['name']!r}: stop at {stop:.1f} m ({where}), "
            f"platform {st['platform_length_m']:g} m on the "
            f"{'right' if st['platform_side'] == 'R' else 'left'}; "
            f"TASC zone: {how}, Doppler radar assumed 10 m past the stop"
        )
        previous = stop
    return [st for st, _ in found_at]


def _assign_gradients(inf: Infrastructure, stations: list[dict[str, Any]]) -> None:
    """Each gradient stretch to the station whose approach it is on (split at platform ends)."""
    bounds = [s["platform_end_m"] for s in stations]
    for st in stations:
        st["gradient"] = []
    for a, b, g in sorted(inf.gradients):
        if g == 0.0:
            continue
        cuts = [a, *(x for x in bounds if a < x < b), b]
        for lo, hi in zip(cuts, cuts[1:], strict=False):
            k = next((i for i, x in enumerate(bounds) if lo < x), len(stations) - 1)
            stations[k]["gradient"].append({"start_m": round(lo, 3), "end_m": round(hi, 3), "permille": g})
    for st in stations:
        if not st["gradient"]:
            del st["gradient"]


def build_line(inf: Infrastructure, vehicle: Vehicle, *, entry_speed_kmh: float, name: str) -> Imported:
    """The line file's data from what the reader found, and the report of the mapping."""
    report: list[str] = []
    if inf.length_m <= 0.0:
        raise ConfigError(inf.source, "tracks", "the chosen tracks have no length")
    if not inf.edges:
        raise ConfigError(
            inf.source, "platform edges", "none on the chosen tracks: a railstop line needs a station"
        )
    line_kmh = inf.line_speed_kmh or max((s for _, _, s in inf.speeds), default=DEFAULT_LINE_SPEED_KMH)
    if inf.line_speed_kmh is None and not inf.speeds:
        report.append(f"no speeds in the file: line speed {DEFAULT_LINE_SPEED_KMH:g} km/h assumed")
    limits = _speed_limits(inf, line_kmh)
    circuits, circuit_sources = _circuits(inf, report)
    signalling = _blocks(inf, circuits, report)
    stations = _stations(inf, vehicle, entry_speed_kmh, limits, line_kmh, report)
    _assign_gradients(inf, stations)
    segments = []
    x, n = 0.0, 1
    while x < inf.length_m - 1e-9:
        end = min(x + SEGMENT_M, inf.length_m)
        segments.append({"id": n, "start_m": round(x, 3), "end_m": round(end, 3)})
        x, n = end, n + 1
    report.append(f"{len(segments)} CBTC segments of {SEGMENT_M:g} m (SPEC §4), not in railML")
    tunnels = [
        {"start_m": round(a, 3), "end_m": round(min(b, inf.length_m), 3), **({"name": t[:64]} if t else {})}
        for a, b, t in inf.tunnels
        if b > a
    ]
    if tunnels:
        report.append(
            f"{_count(len(tunnels), 'tunnel')} taken as GNSS shadows without a repeater "
            "(set repeater = true where a tunnel has one)"
        )
    n_grad = sum(len(s.get("gradient", [])) for s in stations)
    report.append(
        f"{_count(len(limits), 'speed limit')} below the line's {line_kmh:g} km/h; "
        f"{_count(n_grad, 'gradient stretch', 'gradient stretches')}"
    )
    data: dict[str, Any] = {
        "line": {
            "name": (inf.name or name)[:64],
            "speed_limit_kmh": line_kmh,
            "length_m": round(inf.length_m, 3),
        },
        "stations": stations,
        "track": {"circuits": circuits, "tunnels": tunnels},
        "segments": segments,
        "speed_limits": limits,
    }
    if signalling is not None:
        data["signalling"] = signalling
    report.extend(f"not mapped: {s}" for s in inf.skipped)
    return Imported(data=data, report=report, version=inf.version, circuit_sources=tuple(circuit_sources))


def import_railml(
    path: str | Path, vehicle: Vehicle, *, tracks: list[str] | None = None, entry_speed_kmh: float = 60.0
) -> Imported:
    """Read the railML file ``path`` along ``tracks`` (ids in running order; None: its only track)."""
    source = str(path)
    root = parse_xml(read_file_bytes(path), source)
    version = railml_version(root, source)
    reader = read_v3 if version.startswith("3") else read_v2
    inf = reader(root, list(tracks or []), source, version)
    return build_line(inf, vehicle, entry_speed_kmh=entry_speed_kmh, name=Path(path).stem)


def to_toml(imported: Imported, source: str) -> str:
    """The line file's text: the report as its head, each circuit's railML border as a comment."""
    import tomli_w

    data = imported.data
    text = tomli_w.dumps(data)
    head = [
        f"# Imported from {source} (railML {imported.version}) by `railstop import railml`.",
        "# Check every assumption below before trusting a result on this line:",
    ]
    head += [f"#   - {line}" for line in imported.report]
    head.append("# The track circuits start at these railML train detection elements:")
    circuits = data["track"]["circuits"]
    pairs = [f"{c['id']}={s}" for c, s in zip(circuits, imported.circuit_sources, strict=True)]
    head += ["#   " + ", ".join(pairs[i : i + 6]) for i in range(0, len(pairs), 6)]
    return "\n".join(head) + "\n\n" + text
