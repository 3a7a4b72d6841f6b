"""``benchmarks/architecture.py``: its counting checked on a tiny package with known answers, and one
run on the real tree (it must run and find the ``cli`` package at the top of the layers)."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import pytest

from bench_loader import load_benchmark

ROOT = Path(__file__).resolve().parents[2]


arch = load_benchmark("architecture")

LONG_BODY = 119  # lines after the def line: the function is 120 lines long
MANY = 21  # parameters of pkg.physics.train:many

# A package "pkg" with the layers of the real tree: config imports sim (an upward import, and with
# sim importing config a cycle); physics imports sim inside a function (hidden and upward), sim
# imports physics inside a function (hidden, downward); the cli's own hidden import does not count.
FILES = {
    "__init__.py": "",
    "errors.py": '"""Doc\nstring."""\n\n# comment\nclass E(Exception):\n    """Doc."""\n\n    x = 1\n',
    "config/__init__.py": "from pkg.sim import run\n",
    "sim/__init__.py": "",
    "sim/run.py": textwrap.dedent(
        """\
        from __future__ import annotations

        from typing import TYPE_CHECKING

        import pkg.config
        from pkg import errors

        if TYPE_CHECKING:
            from pkg.cli import main


        def hidden():
            from pkg.physics import train
            import json

            return train, json


        class K:
            def method(self, a, b):
                return a + b
        """
    )
    + "\n\ndef long(a, b, c):\n"
    + "".join(f"    x{i} = {i}\n" for i in range(LONG_BODY - 1))
    + "    return a\n",
    "physics/__init__.py": "",
    "physics/train.py": (
        "def many(" + ", ".join(f"p{i}" for i in range(MANY)) + "):\n    return p0\n\n\n"
        "def f():\n    import pkg.sim\n\n    return pkg.sim\n"
    ),
    "cli/__init__.py": (
        "from pkg.sim.run import long\n\n\n"
        "def main():\n    from pkg.config import run\n\n    return run, long\n"
    ),
}


@pytest.fixture
def tiny(tmp_path: Path) -> Path:
    root = tmp_path / "pkg"
    for name, text in FILES.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    return root


def test_packages_lines_and_code_lines(tiny: Path) -> None:
    modules = {m.name: m for m in arch.scan(tiny)}
    assert set(modules) == {
        "pkg",
        "pkg.errors",
        "pkg.config",
        "pkg.sim",
        "pkg.sim.run",
        "pkg.physics",
        "pkg.physics.train",
        "pkg.cli",
    }
    assert modules["pkg"].package == "__root__"
    assert modules["pkg.sim.run"].package == "sim"
    # errors.py: 8 lines, of which only `class E(Exception):` and `x = 1` are code.
    assert (modules["pkg.errors"].lines, modules["pkg.errors"].code) == (8, 2)
    fig = arch.figures(list(modules.values()))
    total = sum(fig["code"]["by_package"].values())
    assert fig["code"]["total"] == total
    assert fig["sim_share"]["code"] == round(fig["code"]["by_package"]["sim"] / total, 4)
    assert fig["lines"]["by_package"]["errors"] == 8
    assert fig["top_packages"] == ["cli"]
    assert fig["unlayered_packages"] == []


def test_imports_by_kind_cycles_and_upward_imports(tiny: Path) -> None:
    fig = arch.figures(arch.scan(tiny))
    # Module-level imports only: the TYPE_CHECKING import of the cli and the hidden ones are not edges.
    assert fig["package_imports"] == {
        "cli -> sim": 1,
        "config -> sim": 1,
        "sim -> config": 1,
        "sim -> errors": 1,
    }
    assert fig["typing_only_package_imports"] == {"sim -> cli": 1}
    assert fig["cycles"]["components"] == [["config", "sim"]]
    assert fig["cycles"]["list"] == ["config -> sim -> config"]
    # The hidden imports close a second cycle (physics <-> sim).
    assert fig["cycles_with_function_imports"]["components"] == [["config", "physics", "sim"]]
    assert fig["cycles_with_function_imports"]["list"] == [
        "config -> sim -> config",
        "physics -> sim -> physics",
    ]
    assert fig["upward_imports"] == ["pkg.config -> pkg.sim.run"]
    assert fig["upward_function_imports"] == ["pkg.physics.train -> pkg.sim"]
    # The cli's own hidden import (pkg.cli:main -> pkg.config) is allowed and not listed.
    assert fig["function_imports_outside_cli"] == {
        "count": 2,
        "list": ["pkg.physics.train:f -> pkg.sim", "pkg.sim.run:hidden -> pkg.physics.train"],
    }
    assert fig["function_imports_outside_cli_external"] == {
        "count": 1,
        "list": ["pkg.sim.run:hidden -> json"],
    }


def test_functions_long_and_with_many_parameters(tiny: Path) -> None:
    modules = arch.scan(tiny)
    funcs = {f.name: f for m in modules for f in m.functions}
    assert funcs["pkg.sim.run:long"].lines == LONG_BODY + 1
    assert funcs["pkg.sim.run:K.method"].params == 2  # self is not counted
    assert funcs["pkg.physics.train:many"].params == MANY
    fig = arch.figures(modules)
    assert fig["longest_functions"][0] == {"name": "pkg.sim.run:long", "lines": LONG_BODY + 1, "params": 3}
    assert len(fig["longest_functions"]) == len(funcs)  # fewer than 10 functions: all of them
    assert [f["name"] for f in fig["functions_over_20_params"]] == ["pkg.physics.train:many"]
    assert fig["functions_over_100_lines"] == 1
    assert fig["functions_over_10_params"] == 1


def test_simple_cycles_start_at_their_smallest_node_and_stop_at_the_cap() -> None:
    edges = [("a", "b"), ("b", "c"), ("c", "a"), ("b", "a"), ("c", "d")]
    cycles, more = arch.simple_cycles(edges)
    assert sorted(cycles) == [["a", "b"], ["a", "b", "c"]] and not more
    assert arch.simple_cycles(edges, cap=1) == ([cycles[0]], True)
    assert arch.strongly_connected(["a", "b", "c", "d"], edges) == [["a", "b", "c"]]


def test_flat_cli_modules_count_as_the_cli_package() -> None:
    assert arch.package_of("railstop.cli_common", "railstop") == "cli"
    assert arch.package_of("railstop.cli.common", "railstop") == "cli"
    assert arch.package_of("railstop", "railstop") == "__root__"


def test_json_output_of_the_tiny_package(tiny: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert arch.main(["--root", str(tiny), "--json"]) == 0
    fig = json.loads(capsys.readouterr().out)
    assert fig["upward_imports"] == ["pkg.config -> pkg.sim.run"]
    assert arch.main(["--root", str(tiny / "errors.py")]) == 2


def test_the_real_tree_has_the_cli_on_top() -> None:
    modules = arch.scan(arch.ROOT)
    fig = arch.figures(modules)
    assert fig["top_packages"] == ["cli"]
    assert fig["unlayered_packages"] == []
    assert fig["code"]["by_package"]["cli"] > 0
    # Nothing below the CLI imports it, at module level or inside a function.
    below = [
        imp
        for m in modules
        if m.package != "cli"
        for imp in m.imports
        if imp.kind != "typing" and imp.imported.split(".")[:2] == ["railstop", "cli"]
    ]
    assert below == []


def test_the_real_tree_keeps_the_layout_targets() -> None:
    """Issue 35's layout targets on the real tree, so that a change breaking one fails here: no
    upward import and no cycle (module level or inside functions), no function of 150 lines or
    more, none over 20 parameters, ``sim/`` under 15 % of the code."""
    fig = arch.figures(arch.scan(arch.ROOT))
    assert fig["upward_imports"] == [] and fig["upward_function_imports"] == []
    assert fig["cycles"]["count"] == 0 and fig["cycles_with_function_imports"]["count"] == 0
    longest = fig["longest_functions"][0]
    assert longest["lines"] < 150, longest
    assert fig["functions_over_20_params"] == []
    assert fig["sim_share"]["code"] < 0.15
