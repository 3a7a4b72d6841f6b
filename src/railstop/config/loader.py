"""Loading TOML data files into validated models, with one-line errors."""

from __future__ import annotations

import re
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

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


def validate(model: type[M], data: dict[str, Any], source: str) -> M:
    """Validate ``data`` against ``model``; the first problem becomes a ConfigError."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        loc = tuple(p for p in err["loc"] if not str(p).startswith("function-after"))
        if err["type"] == "extra_forbidden":
            raise ConfigError(source, format_loc(loc), "unknown key") from None
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
        return tomllib.loads(text)
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
