"""The hazard log as data: every hazard, its safety rule, the unit that enforces it and its tests.

One TOML file per area under ``railstop/data/hazards/`` (``[[hazard]]`` tables).
DESIGN rule 10: every hazard is in the log with its rule, its unit and the
tests that show the rule firing. This module only reads and validates the
files; ``tests/config/test_hazard_log.py`` checks that every named unit imports and
every named test exists, and ``railstop hazards`` renders the log
(``railstop.report.hazard_log``) into ``docs/safety/hazard-log.md``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated

from pydantic import Field, StringConstraints, field_validator

from railstop.config.base import Model
from railstop.config.files import read_text_file
from railstop.config.loader import parse_toml, read_toml, validate
from railstop.errors import ConfigError

HAZARD_ID = re.compile(r"^HZ-([A-Z]+)-(\d{2})$")
#: A pytest node id of a test in the project: ``tests/<path>.py::name`` or ``::Class::name``.
TEST_ID = re.compile(r"^tests/[\w/]+\.py::[A-Za-z_]\w*(::[A-Za-z_]\w*)?$")
#: A dotted path to a module attribute: ``railstop.<module>[.<more>].<Name>``.
UNIT = re.compile(r"^railstop(\.[A-Za-z_]\w*)+$")

Text = Annotated[str, StringConstraints(min_length=3, strip_whitespace=True)]


class Hazard(Model):
    """One entry of the log (every key is required)."""

    id: Annotated[str, Field(pattern=HAZARD_ID.pattern)]
    title: Text
    origin: Text  # the SPEC section, or "review" for a hazard found by review or attack
    cause: Text
    rule: Text
    unit: Annotated[str, Field(pattern=UNIT.pattern)]
    safe_state: Text
    tests: Annotated[list[Annotated[str, Field(pattern=TEST_ID.pattern)]], Field(min_length=1)]

    @field_validator("tests")
    @classmethod
    def _distinct(cls, tests: list[str]) -> list[str]:
        if len(set(tests)) != len(tests):
            raise ValueError("a test is named twice")
        return tests

    @property
    def area(self) -> str:
        m = HAZARD_ID.match(self.id)
        return m.group(1) if m else ""


class HazardFile(Model):
    hazard: Annotated[list[Hazard], Field(min_length=1)]


@dataclass(frozen=True, slots=True, kw_only=True)
class HazardEntry:
    """A hazard and the file it comes from (for messages and the rendered log)."""

    source: str
    hazard: Hazard


def _files(directory: Path | None) -> list[tuple[str, str]]:
    """(source name, text) of every hazard file, sorted by name."""
    if directory is not None:
        if not directory.is_dir():
            raise ConfigError(str(directory), "(folder)", "no such folder")
        out = []
        for p in sorted(directory.glob("*.toml")):
            out.append((str(p), read_text_file(p)))
        return out
    root = resources.files("railstop.data").joinpath("hazards")
    return sorted(
        (f"railstop/data/hazards/{f.name}", f.read_text(encoding="utf-8"))
        for f in root.iterdir()
        if f.name.endswith(".toml")
    )


def load_hazard_log(directory: Path | None = None) -> list[HazardEntry]:
    """Every hazard of the log (the embedded one by default), in file order then id order.

    Refused with a one-line :class:`ConfigError`: a file that is not valid TOML or not the schema,
    an id used twice, or a file whose ids do not share one prefix (one area per file)."""
    entries: list[HazardEntry] = []
    seen: dict[str, str] = {}
    for source, text in _files(directory):
        data = parse_toml(text, source)
        parsed = validate(HazardFile, data, source)
        areas = {h.area for h in parsed.hazard}
        if len(areas) != 1:
            raise ConfigError(
                source, "hazard[].id", "one area per file: ids must share one prefix", sorted(areas)
            )
        for i, h in enumerate(parsed.hazard):
            if h.id in seen:
                raise ConfigError(source, f"hazard[{i}].id", f"already used in {seen[h.id]}", h.id)
            seen[h.id] = source
            entries.append(HazardEntry(source=source, hazard=h))
    return sorted(entries, key=lambda e: (e.source, e.hazard.id))


def load_hazard_file(path: Path) -> list[Hazard]:
    """One hazard file (a user's own, e.g. to check it before adding it)."""
    return validate(HazardFile, read_toml(path), str(path)).hazard
