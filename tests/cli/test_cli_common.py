"""cli.common.with_option_groups: a dataclass of typer options stands for those options."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import pytest
import typer
from typer.testing import CliRunner

from railstop.cli.common import command_group, with_option_groups

SpeedOpt = Annotated[float, typer.Option(min=0.0, max=100.0, help="A speed.")]


@dataclass(frozen=True)
class Group:
    speed: SpeedOpt = 10.0
    name: Annotated[str, typer.Option(help="A name.")] = "x"


@dataclass(frozen=True)
class NoDefault:
    speed: SpeedOpt


def _app(seen: list[object]) -> typer.Typer:
    app = command_group("test")

    @app.command("go")
    @with_option_groups
    def go(*, before: Annotated[int, typer.Option()] = 1, group: Group, after: bool = False) -> None:
        seen.append((before, group, after))

    @app.command("other")
    def other() -> None:  # a second command keeps "go" a sub-command
        pass

    return app


def test_a_group_is_its_options_and_the_command_gets_the_dataclass() -> None:
    seen: list[object] = []
    app = _app(seen)
    result = CliRunner().invoke(app, ["go", "--speed", "3.5", "--before", "7", "--after"])
    assert result.exit_code == 0, result.output
    assert seen == [(7, Group(speed=3.5, name="x"), True)]
    helped = CliRunner().invoke(app, ["go", "--help"])
    for option in ("--before", "--speed", "--name", "--after"):
        assert option in helped.output
    # The group's own checks hold: a speed out of its range is a usage error.
    bad = CliRunner().invoke(app, ["go", "--speed", "101"])
    assert bad.exit_code == 2 and seen == [(7, Group(speed=3.5, name="x"), True)]


def test_a_group_field_without_a_default_or_an_option_given_twice_is_refused() -> None:
    def needs(*, group: NoDefault) -> None: ...

    with pytest.raises(TypeError, match="needs a default"):
        with_option_groups(needs)

    def twice(*, speed: SpeedOpt = 1.0, group: Group) -> None: ...

    with pytest.raises(TypeError, match="given twice"):
        with_option_groups(twice)
