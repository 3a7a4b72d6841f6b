"""Loading TOML data files into validated models, with one-line errors."""

from __future__ import annotations

import difflib
import re
import tomllib
import types
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, TypeVar, Union, get_args, get_origin

from pydantic import BaseModel, RootModel, ValidationError
from pydantic_core import ErrorDetails

from railstop.config.files import read_text_file
from railstop.config.schema import FieldProblem, Line, Station, Vehicle, VehicleFile
from railstop.errors import ConfigError

M = TypeVar("M", bound=BaseModel)

DEFAULT_LINE = "line.toml"
DEFAULT_VEHICLE = "vehicle.toml"


def format_loc(loc: tuple[int | str, ...]) -> str:
    """``('stations', 1, 'tasc', 'x')`` -> ``stations[1].tasc.x``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


def parse_loc(path: str) -> tuple[int | str, ...]:
    """``stations[1].tasc.x`` -> ``('stations', 1, 'tasc', 'x')`` (the inverse of format_loc)."""
    return tuple(int(p[1:-1]) if p.startswith("[") else p for p in re.findall(r"\[\d+\]|[^.\[\]]+", path))


def _lookup(data: Any, loc: tuple[int | str, ...]) -> Any:
    cur = data
    for part in loc:
        try:
            cur = cur[part]
        except (KeyError, IndexError, TypeError):
            return None
    return cur


def _types_of(tp: Any) -> list[Any]:
    """The types a field annotation allows: ``X | None`` and ``Annotated[X, ...]`` unwrapped, a
    root model by its root's type."""
    origin = get_origin(tp)
    if origin is Annotated:
        return _types_of(get_args(tp)[0])
    if origin in (Union, types.UnionType):
        return [t for arg in get_args(tp) for t in _types_of(arg)]
    if isinstance(tp, type) and issubclass(tp, RootModel):
        return _types_of(tp.model_fields["root"].annotation)
    return [tp]


def known_keys(model: type[BaseModel], table: tuple[int | str, ...]) -> list[str]:
    """The keys the table at ``table`` (a validation error's location, less its key) of
    ``model`` accepts; empty where the location cannot be followed."""
    current: list[Any] = _types_of(model)
    for part in table:
        following: list[Any] = []
        for tp in current:
            if isinstance(tp, type) and issubclass(tp, BaseModel):
                if isinstance(part, str) and part in tp.model_fields:
                    following += _types_of(tp.model_fields[part].annotation)
                continue
            origin, args = get_origin(tp), get_args(tp)
            if isinstance(part, int) and origin in (list, tuple, set, frozenset) and args:
                following += [t for arg in args if arg is not Ellipsis for t in _types_of(arg)]
            elif isinstance(part, str) and origin is dict and len(args) == 2:
                following += _types_of(args[1])
        current = following
    keys: list[str] = []
    for tp in current:
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            keys += [k for k in tp.model_fields if k not in keys]
    return keys


def _loc(err: ErrorDetails) -> tuple[int | str, ...]:
    """An error's location, without pydantic's validator steps."""
    return tuple(p for p in err["loc"] if not str(p).startswith("function-after"))


def _unknown_key(
    model: type[BaseModel], errors: list[ErrorDetails]
) -> tuple[tuple[int | str, ...], str] | None:
    """The unknown key to report instead of the first error, with its hint, or None.

    A misspelt required key gives two errors, the required field missing (first) and the
    misspelt key unknown: the unknown key is the one to name, with the closest known key (a
    missing one of the same table first), so that the user sees what to correct. An unknown key
    reported alone gets the same hint.
    """
    first = _loc(errors[0])
    if errors[0]["type"] == "extra_forbidden":
        extra, missing = first, []
    elif errors[0]["type"] == "missing":
        table = first[:-1]
        extras = [_loc(e) for e in errors if e["type"] == "extra_forbidden" and _loc(e)[:-1] == table]
        if not extras:
            return None
        missing = [str(_loc(e)[-1]) for e in errors if e["type"] == "missing" and _loc(e)[:-1] == table]
        # The unknown key closest to a missing one (a misspelling), else the first.
        extra = max(
            extras,
            key=lambda loc: max(
                (difflib.SequenceMatcher(None, str(loc[-1]), m).ratio() for m in missing), default=0.0
            ),
        )
    else:
        return None
    if not extra:
        return None
    key = str(extra[-1])
    close = difflib.get_close_matches(key, missing, n=1) or difflib.get_close_matches(
        key, known_keys(model, extra[:-1]), n=1
    )
    return extra, "unknown key" + (f" (did you mean {close[0]!r}?)" if close else "")


def validate(model: type[M], data: dict[str, Any], source: str) -> M:
    """Validate ``data`` against ``model``; the first problem becomes a ConfigError (an unknown
    key, with the closest known one, before a missing key of the same table)."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        errors = exc.errors(include_url=False)
        unknown = _unknown_key(model, errors)
        if unknown is not None:
            raise ConfigError(source, format_loc(unknown[0]), unknown[1]) from None
        err = errors[0]
        loc = _loc(err)
        problem = (err.get("ctx") or {}).get("error")
        if isinstance(problem, FieldProblem):
            # A whole-model check about one field: name that field and its value.
            loc = (*loc, *parse_loc(problem.field))
        value = err.get("input") if err["type"] != "missing" else None
        if isinstance(value, dict):
            # A model-level check: report the field it talks about where we can.
            value = None
        if value is None and err["type"] != "missing":
            value = _lookup(data, loc) if not isinstance(_lookup(data, loc), dict) else None
        msg = str(err["msg"]).removeprefix("Value error, ")
        raise ConfigError(source, format_loc(loc), msg, value) from None


def with_detectors_only(line: Line, name: str | None) -> Line:
    """``line`` with station ``name`` (None: the first) in its detectors-only variant (SPEC §1
    claim 6, :meth:`Station.detectors_only`); a zone that cannot have it (fewer than 3 detectors
    and no variant layout) is a :class:`ConfigError` naming the field and its value."""
    st = line.station(name)
    variant = validate(Station, st.detectors_only_data(), f"station {st.name!r}: no detectors-only variant")
    return line.model_copy(update={"stations": [variant if s is st else s for s in line.stations]})


def read_toml(path: Path) -> dict[str, Any]:
    """A user's TOML file (``railstop.config.files.read_text_file``: a regular file of bounded size)."""
    return parse_toml(read_text_file(path), str(path))


def parse_toml(text: str, source: str) -> dict[str, Any]:
    """TOML text, or one ConfigError naming ``source`` (a syntax error, nesting too deep)."""
    try:
        # A UTF-8 byte-order mark (some Windows editors write one) is not part of the TOML.
        return tomllib.loads(text.removeprefix("\ufeff"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(source, "(toml syntax)", str(exc)) from None
    except RecursionError:
        raise ConfigError(source, "(toml syntax)", "arrays or tables nested too deeply") from None


def data_text(name: str) -> tuple[str, dict[str, Any]]:
    ref = resources.files("railstop.data").joinpath(name)
    return f"railstop/data/{name}", tomllib.loads(ref.read_text(encoding="utf-8"))


def line_source(path: str | Path | None) -> str:
    """How messages name a line file (``None``: the embedded default line)."""
    return f"railstop/data/{DEFAULT_LINE}" if path is None else str(path)


def load_line(path: str | Path | None = None) -> Line:
    """Load a line file; ``None`` gives the embedded default line."""
    if path is None:
        source, data = data_text(DEFAULT_LINE)
    else:
        source, data = str(path), read_toml(Path(path))
    return validate(Line, data, source)


def load_vehicle(path: str | Path | None = None) -> Vehicle:
    """Load a vehicle file; ``None`` gives the embedded default vehicle."""
    if path is None:
        source, data = data_text(DEFAULT_VEHICLE)
    else:
        source, data = str(path), read_toml(Path(path))
    return validate(VehicleFile, data, source).vehicle


def default_line() -> Line:
    return load_line(None)


def default_vehicle() -> Vehicle:
    return load_vehicle(None)
