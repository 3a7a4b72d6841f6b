"""The reference of every data file a user writes, generated from the schemas that check them.

Each file's format is the pydantic model its loader validates against; this module walks
that model (its tables, arrays of tables and keys) and writes, per key: the type and unit,
the default, the allowed range and the meaning. The meaning is the source's own comment on
the field (the comment lines directly above it, and one on its line): the code and its
reference cannot drift apart. ``railstop formats --markdown docs/file-formats.md`` writes
it; a test fails when the file in ``docs/`` is not what the code renders.
"""

from __future__ import annotations

import inspect
import io
import textwrap
import tokenize
import types
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import annotated_types as at
from pydantic import BaseModel
from pydantic.fields import FieldInfo

# Units by a key's suffix (the schemas are SI unless the name says otherwise, DESIGN rule 5).
_UNITS: tuple[tuple[str, str], ...] = (
    ("_n_per_mps2", "N/(m/s)²"),
    ("_n_per_mps", "N/(m/s)"),
    ("_mps3", "m/s³"),
    ("_mps2", "m/s²"),
    ("_m2", "m²"),
    ("_mps", "m/s"),
    ("_kmh", "km/h"),
    ("_permille", "‰"),
    ("permille", "‰"),
    ("_pct", "%"),
    ("_ppm", "ppm"),
    ("_ms", "ms"),
    ("_mm", "mm"),
    ("_kg", "kg"),
    ("_hz", "Hz"),
    ("_bps", "bit/s"),
    ("_m", "m"),
    ("_s", "s"),
    ("_h", "h"),
    ("_n", "N"),
    ("_w", "W"),
)


def unit_of(key: str) -> str:
    """The unit a key's name gives (``""``: none, a count, a ratio or text)."""
    for suffix, unit in _UNITS:
        if key.endswith(suffix):
            return unit
    return ""


@dataclass(frozen=True, slots=True)
class FileFormat:
    """One kind of data file: its name, the model of its whole text, where the embedded
    default lives and which option takes the user's own."""

    name: str
    title: str
    model: type[BaseModel]
    embedded: str  # the package's default file ("": none)
    option: str  # the command-line option that reads one
    about: str
    short: str  # what it is, in a few words (the list of files)
    root: str = ""  # the header the model's own keys sit under (media: one table per medium)


@dataclass(frozen=True, slots=True)
class Key:
    """One key of a table."""

    key: str
    type: str
    unit: str
    default: str
    range: str
    meaning: str


@dataclass(frozen=True, slots=True)
class Table:
    """One table of a file: its TOML header (``""``: the top level), what it is, its keys."""

    header: str
    about: str
    keys: tuple[Key, ...]
    same_as: str = ""  # the table whose keys these are, met earlier in the same file


# ---------------------------------------------------------------------- the source's comments


@cache
def field_comments(cls: type) -> dict[str, str]:
    """Per field defined in ``cls`` itself: the comment lines directly above it and on its line."""
    try:
        lines, _ = inspect.getsourcelines(cls)
    except (OSError, TypeError):
        return {}
    source = textwrap.dedent("".join(lines))
    comments: dict[int, str] = {}  # line -> comment text
    code_lines: set[int] = set()
    skip = {tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT, tokenize.ENDMARKER}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            comments[tok.start[0]] = tok.string.lstrip("#").strip()
        elif tok.type not in skip:
            code_lines.update(range(tok.start[0], tok.end[0] + 1))
    own = set(inspect.get_annotations(cls))
    out: dict[str, str] = {}
    depth = None
    for n, text in enumerate(source.splitlines(), start=1):
        stripped = text.lstrip()
        indent = len(text) - len(stripped)
        if depth is None and n > 1 and stripped and not stripped.startswith("#"):
            depth = indent  # the class body's indentation
        name = stripped.split(":", 1)[0].strip() if ":" in stripped else ""
        if indent != depth or name not in own or name in out:
            continue
        above: list[str] = []
        k = n - 1
        while k in comments and k not in code_lines:
            above.insert(0, comments[k])
            k -= 1
        parts = [" ".join(above)] if above else []
        if n in comments:
            parts.append(comments[n])
        out[name] = " ".join(p for p in parts if p)
    return out


def meaning_of(model: type[BaseModel], name: str) -> str:
    """The comment of ``model``'s field ``name``, from the class that declares it."""
    for cls in model.__mro__:
        if name in inspect.get_annotations(cls):
            return field_comments(cls).get(name, "")
    return ""


def _about(model: type[BaseModel]) -> str:
    """The first paragraph of the model's own docstring (not one it inherits)."""
    doc = inspect.cleandoc(model.__dict__.get("__doc__") or "")
    return " ".join(doc.split("\n\n", 1)[0].split())


# ---------------------------------------------------------------------- types, ranges, defaults


def _strip(tp: Any) -> tuple[Any, list[Any]]:
    """The type under ``Annotated`` and its metadata."""
    meta: list[Any] = []
    while get_origin(tp) is Annotated:
        args = get_args(tp)
        tp, meta = args[0], [*meta, *args[1:]]
    return tp, meta


def _constraints(meta: list[Any]) -> list[Any]:
    out: list[Any] = []
    for m in meta:
        if isinstance(m, FieldInfo):
            out += _constraints(list(m.metadata))
        elif isinstance(m, at.Gt | at.Ge | at.Lt | at.Le | at.MinLen | at.MaxLen):
            out.append(m)
    return out


def _num(x: object) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


def range_text(meta: list[Any], count: str = "items") -> str:
    """``0 < x ≤ 2``, ``x ≥ 1``, ``1 to 64 characters``: the bounds the schema enforces
    (``count``: what a length counts)."""
    lo = hi = ""
    items: list[str] = []
    for c in _constraints(meta):
        if isinstance(c, at.Gt):
            lo = f"{_num(c.gt)} <"
        elif isinstance(c, at.Ge):
            lo = f"{_num(c.ge)} ≤"
        elif isinstance(c, at.Lt):
            hi = f"< {_num(c.lt)}"
        elif isinstance(c, at.Le):
            hi = f"≤ {_num(c.le)}"
        elif isinstance(c, at.MinLen):
            items.append(f"at least {c.min_length}")
        elif isinstance(c, at.MaxLen):
            items.append(f"at most {c.max_length}")
    if len(items) == 2:
        items = [f"{items[0].split()[-1]} to {items[1].split()[-1]}"]
    if lo and hi:
        text = f"{lo} x {hi}"
    elif lo:
        text = f"x {'>' if lo.endswith('<') else '≥'} {lo.split()[0]}"
    elif hi:
        text = f"x {hi}"
    else:
        text = ""
    if items:
        one = items[0].split()[-1] == "1" and " to " not in items[0]
        what = count.removesuffix("s") if one else count
        text = ", ".join([t for t in (text,) if t] + [f"{items[0]} {what}"])
    return text


def _models_in(tp: Any) -> list[type[BaseModel]]:
    tp, _ = _strip(tp)
    if inspect.isclass(tp) and issubclass(tp, BaseModel):
        return [tp]
    out: list[type[BaseModel]] = []
    for a in get_args(tp):
        out += _models_in(a)
    return out


def _toml_literal(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    return _num(v)


def type_text(tp: Any) -> tuple[str, str]:
    """(the type in words, the range of a list's items or of the value itself)."""
    tp, meta = _strip(tp)
    origin = get_origin(tp)
    if origin in (Union, types.UnionType):
        args = [a for a in get_args(tp) if a is not type(None)]
        texts = [type_text(a) for a in args]
        optional = len(args) < len(get_args(tp))
        words = " or ".join(t for t, _ in texts) + (" (optional)" if optional else "")
        return words, next((r for _, r in texts if r), range_text(meta))
    if origin is Literal:
        return "one of " + ", ".join(_toml_literal(a) for a in get_args(tp)), ""
    if origin in (list, tuple):
        args = [a for a in get_args(tp) if a is not Ellipsis]
        inner, inner_range = type_text(args[0]) if args else ("value", "")
        if args and _models_in(args[0]):
            return "array of tables", range_text(meta)
        each = f"each {inner_range}" if inner_range else ""
        if origin is tuple and len(args) > 1:
            return f"{len(args)} numbers", each
        return f"list of {inner}s", each
    if origin is dict:
        kv = get_args(tp)
        inner = type_text(kv[1])[0] if len(kv) == 2 else "value"
        return f"table of named {inner}s", ""
    if inspect.isclass(tp) and issubclass(tp, BaseModel):
        return "table", ""
    names: dict[Any, str] = {float: "number", int: "integer", bool: "true or false", str: "text"}
    return names.get(tp, getattr(tp, "__name__", str(tp))), range_text(meta, "characters")


def default_text(f: FieldInfo) -> str:
    if f.is_required():
        return "required"
    value = f.default_factory() if f.default_factory is not None else f.default  # type: ignore[call-arg]
    if value is None:
        return "none"
    if isinstance(value, BaseModel):
        return "its defaults"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_literal(v) for v in value) + "]" if value else "[]"
    if isinstance(value, dict):
        return "{}" if not value else "(table)"
    return _toml_literal(value)


# ---------------------------------------------------------------------- the walk


def tables(model: type[BaseModel], header: str = "", seen: dict[type, str] | None = None) -> Iterator[Table]:
    """The tables of a file whose text ``model`` validates, top first, in the fields' order
    (an array of tables' header in double brackets, as TOML writes it; a table of named tables
    with ``<name>`` in its header). A model met again in the same file is told by reference."""
    seen = {} if seen is None else seen
    same_as = seen.get(model, "")
    seen.setdefault(model, header.strip("[]"))
    keys: list[Key] = []
    below: list[tuple[str, type[BaseModel]]] = []
    for name, f in model.model_fields.items():
        key = f.alias or name
        words, rng = type_text(f.annotation)
        _, meta = _strip(f.annotation)
        count = "characters" if words.startswith("text") else "items"
        rng = ", ".join(r for r in (range_text([*f.metadata, *meta], count), rng) if r)
        keys.append(
            Key(
                key=key,
                type=words,
                unit=unit_of(key),
                default=default_text(f),
                range=rng,
                meaning=meaning_of(model, name),
            )
        )
        base = header.strip("[]")
        path = f"{base}.{key}" if base else key
        if words.startswith("table of"):
            path += ".<name>"
        for sub in _models_in(f.annotation):
            below.append((f"[{path}]" if words == "array of tables" else path, sub))
    yield Table(header=header, about=_about(model), keys=tuple(keys), same_as=same_as)
    for path, sub in below:
        yield from tables(sub, path, seen)


def missing_meanings(fmt: FileFormat) -> list[str]:
    """Every key of a file without a meaning (``header.key``): the reference must have none."""
    return [
        f"{t.header}.{k.key}" if t.header else k.key
        for t in tables(fmt.model, fmt.root)
        for k in t.keys
        if not k.meaning
    ]


# ---------------------------------------------------------------------- the files


def file_formats() -> tuple[FileFormat, ...]:
    """Every data file a user may write, in the order of the reference."""
    from railstop.config.doors import DoorsFile
    from railstop.config.driver import DriverFile
    from railstop.config.faults import Faults
    from railstop.config.media import ChannelParams
    from railstop.config.operation import Operation
    from railstop.config.platform import PlatformFile
    from railstop.config.schema import Line, VehicleFile

    return (
        FileFormat(
            "line",
            "Line",
            Line,
            "railstop/data/line.toml",
            "--line",
            "The line: its stations with their TASC zones (SPEC §1), the track circuits, GNSS "
            "shadows and clocks of the position chain (SPEC §2), the segments, blocks and speed "
            "limits of the line with many trains, and the CBTC settings (SPEC §4).",
            short="the line, its stations, track circuits, signalling and CBTC",
        ),
        FileFormat(
            "vehicle",
            "Vehicle",
            VehicleFile,
            "railstop/data/vehicle.toml",
            "--vehicle",
            "The train: its mass and resistance, the brake chain (SPEC §1), traction, the "
            "onboard positioning (SPEC §2) and the train's own overrun guard.",
            short="the train: masses, brakes, traction, positioning",
        ),
        FileFormat(
            "operation",
            "Operation",
            Operation,
            "railstop/data/operation/default.toml",
            "--operation",
            "The service on the line: how many trains enter, when, at what speed, the station "
            "controller and the dwells.",
            short="the service of a line run: trains, headway, dwells",
        ),
        FileFormat(
            "doors",
            "Doors",
            DoorsFile,
            "railstop/data/doors.toml",
            "--doors",
            "The door / platform screen door interlock of driverless trains (SPEC §5): door "
            "timings, the stop confirmation, the door link.",
            short="the door / PSD interlock of driverless trains",
        ),
        FileFormat(
            "platform",
            "Platform",
            PlatformFile,
            "railstop/data/platform.toml",
            "--platform",
            "Accurate stopping of manually driven trains (SPEC §3): platform stop sensors, "
            "lamps, the door camera and the approach modes.",
            short="manual stopping: stop sensors, lamps, door camera",
        ),
        FileFormat(
            "driver",
            "Driver",
            DriverFile,
            "railstop/data/driver.toml",
            "--driver",
            "The model of a human driver for the manual stop (SPEC §3): levels of skill, reaction, re-stops.",
            short="the human driver of the manual stop",
        ),
        FileFormat(
            "faults",
            "Faults",
            Faults,
            "",
            "--faults",
            "Faults a line run injects (SPEC §4): radio outages of given trains, random outages, "
            "the radio's loss and bursts, zone-controller restarts.",
            short="radio outages, radio loss and zone-controller restarts of a line run",
        ),
        FileFormat(
            "media",
            "Media",
            ChannelParams,
            "railstop/data/media.toml",
            "medium = NAME (a station's tasc.medium)",
            "The transmission media of the links (SPEC §1 RF, SPEC §5 loop, transponder, radio): "
            "one table per medium, named by the data that use it. The package's file is the one "
            "read; a station names one of its media.",
            short="the links' transmission media",
            root="<medium>",
        ),
    )


def disturbances_section() -> list[str]:
    """The disturbance file: one key per parameter, each a distribution (its own grammar)."""
    from railstop.config.disturbances import parameter_specs

    out = [
        '<a id="disturbances"></a>',
        "",
        "## Disturbances",
        "",
        "The random draws of a stop campaign (SPEC §1: what a ground-based TASC stop must "
        "tolerate). Given with `--disturbances FILE` or a built-in name (`nominal`, `standard`: "
        "`railstop/data/disturbances/`). Each key is a parameter and its value a distribution: "
        "`{fixed = x}`, `{uniform = [lo, hi]}`, `{normal = [mean, sd], clip = [lo, hi]}` (a "
        "normal needs its clip) or `{choice = [a, b, ...]}`; a `*_probability` is a plain number. "
        "Every value a distribution can give must lie in the parameter's range. A parameter the "
        "file leaves out takes its nominal value; `description` (text) says what the set is for.",
        "",
        "| key | unit | range | meaning |",
        "|---|---|---|---|",
    ]
    for name, unit, rng, meaning in parameter_specs():
        out.append(f"| `{name}` | {_cell(unit)} | {_cell(rng)} | {_cell(meaning)} |")
    return [*out, ""]


def operators_section() -> list[str]:
    """The operators file of the control room (a plain TOML of its own, no schema model)."""
    from railstop.live.operators import ITERATIONS, MAX_OPERATOR_ID, MIN_CREDENTIAL_CHARS

    return [
        '<a id="operators"></a>',
        "",
        "## Operators",
        "",
        "The control room's operators (`railstop office serve --operators FILE`): one table "
        "`[operators.NAME]` per operator (a name of 1 to 40 letters, digits, `_`, `.` or `-`). "
        "Write it with `railstop office add-operator FILE NAME`, which asks for the credential "
        f"(at least {MIN_CREDENTIAL_CHARS} characters, never on the command line) and writes the "
        "file with mode 0600; a file that group or others may read is refused.",
        "",
        "| key | type | range | meaning |",
        "|---|---|---|---|",
        f"| `id` | integer | 1 ≤ x ≤ {MAX_OPERATOR_ID} | the operator's id, carried by every command "
        "telegram the operator sends (SPEC §4 step 5, §5) |",
        f"| `pbkdf2_sha256` | text | `{ITERATIONS}$<salt hex>$<hash hex>` | the credential, stored "
        "only as a salted PBKDF2-SHA256 hash |",
        "",
    ]


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ") or "—"


def render_markdown(formats: tuple[FileFormat, ...] | None = None) -> str:
    """The whole reference as Markdown."""
    formats = formats if formats is not None else file_formats()
    out = [
        "# Data file reference",
        "",
        "Generated by `railstop formats --markdown docs/file-formats.md` from the schemas that "
        "check the files (`railstop.config`); a test fails when this page and the code differ. "
        "Every file is TOML. A key the schema does not know is an error (a misspelt key never "
        "passes silently); a value outside its range is an error naming the file, the key and "
        'the value; a number written as a string (`"1200"`) is an error too, never converted. '
        "Units are SI unless the key's name says otherwise (`_kmh`, `_permille`, "
        "`_pct`, `_ms`, `_mm`). `railstop init DIR` writes a commented copy of each embedded "
        "file to start from.",
        "",
        "Files:",
        "",
    ]
    for fmt in formats:
        out.append(f"- [{fmt.title}](#{fmt.name}): {fmt.short}")
    out += [
        "- [Disturbances](#disturbances): the random draws of a stop campaign",
        "- [Operators](#operators): the control room's operators and their credentials",
        "",
    ]
    for fmt in formats:
        out += [f'<a id="{fmt.name}"></a>', "", f"## {fmt.title}", "", fmt.about, ""]
        where = f"The embedded default: `{fmt.embedded}`." if fmt.embedded else "No embedded default."
        given = (
            f"Given with `{fmt.option} FILE`." if fmt.option.startswith("--") else f"Used as `{fmt.option}`."
        )
        out += [f"{given} {where}", ""]
        for table in tables(fmt.model, fmt.root):
            title = f"`[{table.header}]`" if table.header else "top level"
            out += [f"### {fmt.title}: {title}", ""]
            if table.same_as:
                out += [f"The same keys as `[{table.same_as}]`.", ""]
                continue
            if table.about:
                out += [table.about, ""]
            out += ["| key | type | unit | default | range | meaning |", "|---|---|---|---|---|---|"]
            for k in table.keys:
                out.append(
                    f"| `{k.key}` | {_cell(k.type)} | {_cell(k.unit)} | {_cell(k.default)} | "
                    f"{_cell(k.range)} | {_cell(k.meaning)} |"
                )
            out.append("")
    out += disturbances_section()
    out += operators_section()
    return "\n".join(out).rstrip() + "\n"
