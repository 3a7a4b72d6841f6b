"""Architecture figures of the source tree (the "one system" issue): size, imports, layers, functions.

    python benchmarks/architecture.py [--root src/railstop] [--json]

Read from the source with ``ast`` and ``tokenize`` only (nothing is imported or run):

- lines per top-level package (a top-level module such as ``errors.py`` is a package of its own):
  ``lines`` are physical lines, ``code`` the lines that hold a token other than a comment or a
  docstring; the share of ``sim/`` in both;
- the import graph between the packages. Every import of the tree's own modules is one of
  ``module`` (run when the module loads, also under a module-level ``if``/``try``), ``typing`` (in an
  ``if TYPE_CHECKING:`` block: never run) or ``function`` (inside a function: run when it is
  called). The graph is made of the ``module`` imports; the ``function`` imports outside ``cli/`` are
  counted and listed (the rule: no hidden imports outside the CLI unless to break a real cycle),
  with the third-party ones as well;
- its cycles at package level: the strongly connected packages and their simple cycles, for the
  ``module`` graph and for the graph that adds the ``function`` imports;
- the imports that go upward against the layer order below (``importer -> imported``, modules);
- the 10 longest functions (``def`` line to the last line, decorators not counted), every
  function over 20 parameters, how many are over 100 lines and over 10 parameters (every declared
  parameter, ``*args`` and ``**kwargs`` included, but a method's ``self`` / ``cls``).

Nothing is asserted: the figures are printed (``--json``: one JSON object).
"""

from __future__ import annotations

import argparse
import ast
import io
import json
import sys
import tokenize
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1] / "src" / "railstop"

#: The layers, lowest first (the issue's order); packages on one level may import each other.
LAYERS: tuple[tuple[str, ...], ...] = (
    # [interpretation] The root package (``__init__.py``: the version only) and ``data`` (the
    # embedded TOML files, no code) are foundations: they import nothing of the tree.
    (
        *(
            "errors",
            "messages",
            "units",
            "quantities",
            "streams",
            "stream_cores",
            "jit",
            "clock",
            "provenance",
            "controllers",
        ),
        *("__root__", "data"),
    ),
    ("config",),
    ("physics", "sensors", "control"),
    ("wayside", "onboard"),
    ("link",),
    ("model",),
    ("nodes",),
    ("sim", "verify", "live", "store", "report", "stats"),
    ("cli",),
)
LEVEL: dict[str, int] = {pkg: level for level, pkgs in enumerate(LAYERS) for pkg in pkgs}
TOP = "cli"
SHARE_OF = "sim"
ROOT_PACKAGE = "__root__"  # the root package's own __init__.py
LONG_LINES, MANY_PARAMS, VERY_MANY_PARAMS, LONGEST = 100, 10, 20, 10
CYCLE_CAP = 200  # simple cycles listed per graph at most (the count says when more exist)


@dataclass(frozen=True, slots=True, kw_only=True)
class Import:
    """One import of a module of the tree: ``importer`` (module) imports ``imported`` (module)."""

    importer: str
    imported: str
    kind: str  # "module", "typing" or "function"
    function: str | None  # the enclosing function (qualified) of a "function" import
    line: int


@dataclass(frozen=True, slots=True, kw_only=True)
class Function:
    """One ``def``: its qualified name (``module:Class.name``), lines and parameters."""

    name: str
    lines: int
    params: int


@dataclass(slots=True, kw_only=True)
class Module:
    """One source file: its dotted name, top-level package, sizes, imports and functions."""

    name: str
    package: str
    lines: int
    code: int
    imports: list[Import] = field(default_factory=list)
    external: list[Import] = field(default_factory=list)  # third-party / stdlib imports in functions
    functions: list[Function] = field(default_factory=list)


def package_of(module: str, root: str) -> str:
    """The top-level package of ``root.a.b`` (``a``), ``__root__`` for the root package itself.

    [interpretation] The flat CLI (``cli.py`` and ``cli_*.py`` before the ``cli/`` package) is
    counted as the ``cli`` package, so that figures before and after the move compare.
    """
    parts = module.split(".")
    if parts[0] != root:
        raise ValueError(f"{module} is not in {root}")
    if len(parts) == 1:
        return ROOT_PACKAGE
    return "cli" if parts[1].startswith("cli_") else parts[1]


def _code_lines(source: str, tree: ast.Module) -> int:
    """Lines that hold a token other than a comment or a docstring (blank lines do not count)."""
    doc: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if (
                body
                and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)
            ):
                doc.update(range(body[0].lineno, (body[0].end_lineno or body[0].lineno) + 1))
    skip = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT}
    lines: set[int] = set()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type in skip or tok.type == tokenize.ENDMARKER:
            continue
        for line in range(tok.start[0], tok.end[0] + 1):
            if line not in doc:
                lines.add(line)
    return len(lines)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _params(node: ast.FunctionDef | ast.AsyncFunctionDef, method: bool) -> int:
    a = node.args
    names = [*a.posonlyargs, *a.args]
    n = len(names) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
    if method and names and names[0].arg in ("self", "cls"):
        n -= 1
    return n


class _Walker(ast.NodeVisitor):
    """Collects a module's imports (with their kind) and its functions."""

    def __init__(self, module: str, is_package: bool, known: set[str], root: str) -> None:
        self.module = module
        self.is_package = is_package
        self.known = known
        self.root = root
        self.scope: list[str] = []  # qualified names of the enclosing classes / functions
        self.in_function: list[str] = []
        self.type_checking = 0
        self.imports: list[Import] = []
        self.external: list[Import] = []
        self.functions: list[Function] = []
        self.class_depth: list[bool] = []  # per scope: is it a class

    # -- scopes
    def visit_ClassDef(self, node: ast.ClassDef) -> None:
        self.scope.append(node.name)
        self.class_depth.append(True)
        self.generic_visit(node)
        self.scope.pop()
        self.class_depth.pop()

    def _function(self, node: ast.FunctionDef | ast.AsyncFunctionDef) -> None:
        method = bool(self.class_depth) and self.class_depth[-1]
        qual = ".".join([*self.scope, node.name])
        self.functions.append(
            Function(
                name=f"{self.module}:{qual}",
                lines=(node.end_lineno or node.lineno) - node.lineno + 1,
                params=_params(node, method),
            )
        )
        self.scope.append(node.name)
        self.class_depth.append(False)
        self.in_function.append(qual)
        self.generic_visit(node)
        self.in_function.pop()
        self.class_depth.pop()
        self.scope.pop()

    visit_FunctionDef = _function
    visit_AsyncFunctionDef = _function

    def visit_If(self, node: ast.If) -> None:
        if _is_type_checking(node.test):
            self.type_checking += 1
            for child in node.body:
                self.visit(child)
            self.type_checking -= 1
            for child in node.orelse:
                self.visit(child)
        else:
            self.generic_visit(node)

    # -- imports
    def _resolve(self, name: str) -> str | None:
        """The tree's module that ``name`` (dotted) names, or its nearest known parent; None if outside."""
        if name != self.root and not name.startswith(self.root + "."):
            return None
        while name not in self.known and "." in name:
            name = name.rsplit(".", 1)[0]
        return name

    def _add(self, targets: Sequence[str], line: int, outside: str) -> None:
        kind = "function" if self.in_function else ("typing" if self.type_checking else "module")
        function = self.in_function[-1] if self.in_function else None
        found = {t for t in (self._resolve(name) for name in targets) if t is not None}
        for target in sorted(found):
            if target != self.module:
                self.imports.append(
                    Import(importer=self.module, imported=target, kind=kind, function=function, line=line)
                )
        if not found and kind == "function":
            self.external.append(
                Import(importer=self.module, imported=outside, kind=kind, function=function, line=line)
            )

    def visit_Import(self, node: ast.Import) -> None:
        names = [alias.name for alias in node.names]
        self._add(names, node.lineno, ", ".join(names))

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        if node.level:
            base = self.module.split(".")
            if not self.is_package:
                base = base[:-1]
            base = base[: len(base) - (node.level - 1)]
            prefix = ".".join(base + ([node.module] if node.module else []))
        else:
            prefix = node.module or ""
        # ``from a import b`` names module ``a.b`` where it is one, else ``a``.
        targets = [f"{prefix}.{alias.name}" for alias in node.names if alias.name != "*"] or [prefix]
        self._add(targets, node.lineno, prefix)


def scan(root: Path = ROOT) -> list[Module]:
    """Every module under ``root`` (a package folder), with what the figures need."""
    name = root.name
    files = sorted(p for p in root.rglob("*.py") if "__pycache__" not in p.parts)

    def dotted(path: Path) -> str:
        rel = path.relative_to(root).with_suffix("").parts
        if rel[-1] == "__init__":
            rel = rel[:-1]
        return ".".join((name, *rel))

    known = {dotted(p) for p in files}
    modules = []
    for path in files:
        source = path.read_text(encoding="utf-8")
        tree = ast.parse(source, filename=str(path))
        mod = dotted(path)
        walker = _Walker(mod, path.name == "__init__.py", known, name)
        walker.visit(tree)
        modules.append(
            Module(
                name=mod,
                package=package_of(mod, name),
                lines=len(source.splitlines()),
                code=_code_lines(source, tree),
                imports=walker.imports,
                external=walker.external,
                functions=walker.functions,
            )
        )
    return modules


def package_edges(modules: Sequence[Module], kinds: Sequence[str]) -> Counter[tuple[str, str]]:
    """(importer package, imported package) -> imports, for imports of ``kinds`` across packages."""
    pkg = {m.name: m.package for m in modules}
    edges: Counter[tuple[str, str]] = Counter()
    for m in modules:
        for imp in m.imports:
            if imp.kind in kinds and pkg[imp.imported] != m.package:
                edges[(m.package, pkg[imp.imported])] += 1
    return edges


def strongly_connected(nodes: Sequence[str], edges: Sequence[tuple[str, str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan), each sorted, sorted."""
    succ: dict[str, list[str]] = {n: [] for n in nodes}
    for a, b in edges:
        succ.setdefault(a, []).append(b)
        succ.setdefault(b, [])
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in succ[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(succ):
        if v not in index:
            visit(v)
    return sorted(found)


def simple_cycles(edges: Sequence[tuple[str, str]], cap: int = CYCLE_CAP) -> tuple[list[list[str]], bool]:
    """The simple cycles (each from its smallest node), at most ``cap``; True if more were left off."""
    succ: dict[str, list[str]] = {}
    for a, b in edges:
        succ.setdefault(a, []).append(b)
    for v in succ.values():
        v.sort()
    cycles: list[list[str]] = []

    def walk(start: str, path: list[str], seen: set[str]) -> Iterator[list[str]]:
        for w in succ.get(path[-1], []):
            if w == start:
                yield [*path]
            elif w > start and w not in seen:
                seen.add(w)
                yield from walk(start, [*path, w], seen)
                seen.discard(w)

    for start in sorted(succ):
        for cycle in walk(start, [start], {start}):
            if len(cycles) == cap:
                return cycles, True
            cycles.append(cycle)
    return cycles, False


def upward(modules: Sequence[Module], kinds: Sequence[str]) -> list[str]:
    """``importer -> imported`` (modules) where the imported package lies on a higher layer."""
    pkg = {m.name: m.package for m in modules}
    out = []
    for m in modules:
        for imp in m.imports:
            lo, hi = LEVEL.get(m.package), LEVEL.get(pkg[imp.imported])
            if imp.kind in kinds and lo is not None and hi is not None and hi > lo:
                out.append(f"{m.name} -> {imp.imported}")
    return sorted(set(out))


def figures(modules: Sequence[Module]) -> dict[str, Any]:
    """Every figure of the issue, as plain data (what ``--json`` prints)."""
    lines: Counter[str] = Counter()
    code: Counter[str] = Counter()
    for m in modules:
        lines[m.package] += m.lines
        code[m.package] += m.code
    total_lines, total_code = sum(lines.values()), sum(code.values())
    packages = sorted(lines, key=lambda p: (-code[p], p))
    graph = package_edges(modules, ("module",))
    with_functions = package_edges(modules, ("module", "function"))
    typing_only = package_edges(modules, ("typing",))
    hidden = [
        f"{imp.importer}:{imp.function} -> {imp.imported}"
        for m in modules
        if m.package != TOP
        for imp in m.imports
        if imp.kind == "function"
    ]
    hidden_external = [
        f"{imp.importer}:{imp.function} -> {imp.imported}"
        for m in modules
        if m.package != TOP
        for imp in m.external
    ]
    cycles, more = simple_cycles(sorted(graph))
    cycles_f, more_f = simple_cycles(sorted(with_functions))
    funcs = [f for m in modules for f in m.functions]
    longest = sorted(funcs, key=lambda f: (-f.lines, f.name))[:LONGEST]
    unlayered = sorted(p for p in lines if p not in LEVEL)
    top = [p for p in lines if p in LEVEL and LEVEL[p] == len(LAYERS) - 1]
    return {
        "modules": len(modules),
        "lines": {"total": total_lines, "by_package": {p: lines[p] for p in packages}},
        "code": {"total": total_code, "by_package": {p: code[p] for p in packages}},
        "sim_share": {
            "lines": round(lines[SHARE_OF] / total_lines, 4) if total_lines else 0.0,
            "code": round(code[SHARE_OF] / total_code, 4) if total_code else 0.0,
        },
        "top_packages": sorted(top),
        "unlayered_packages": unlayered,
        "package_imports": {f"{a} -> {b}": n for (a, b), n in sorted(graph.items())},
        "typing_only_package_imports": {
            f"{a} -> {b}": n for (a, b), n in sorted(typing_only.items()) if (a, b) not in graph
        },
        "function_imports_outside_cli": {"count": len(hidden), "list": sorted(hidden)},
        "function_imports_outside_cli_external": {
            "count": len(hidden_external),
            "list": sorted(hidden_external),
        },
        "cycles": {
            "components": strongly_connected(sorted(lines), sorted(graph)),
            "count": len(cycles),
            "more": more,
            "list": [" -> ".join([*c, c[0]]) for c in cycles],
        },
        "cycles_with_function_imports": {
            "components": strongly_connected(sorted(lines), sorted(with_functions)),
            "count": len(cycles_f),
            "more": more_f,
            "list": [" -> ".join([*c, c[0]]) for c in cycles_f],
        },
        "upward_imports": upward(modules, ("module",)),
        "upward_function_imports": upward(modules, ("function",)),
        "functions": len(funcs),
        "longest_functions": [asdict(f) for f in longest],
        f"functions_over_{VERY_MANY_PARAMS}_params": [
            asdict(f) for f in sorted(funcs, key=lambda f: (-f.params, f.name)) if f.params > VERY_MANY_PARAMS
        ],
        f"functions_over_{LONG_LINES}_lines": sum(f.lines > LONG_LINES for f in funcs),
        f"functions_over_{MANY_PARAMS}_params": sum(f.params > MANY_PARAMS for f in funcs),
    }


def _print(fig: dict[str, Any]) -> None:
    lines, code, share = fig["lines"], fig["code"], fig["sim_share"]
    print(f"{fig['modules']} modules, {lines['total']} lines, {code['total']} code lines")
    print(f"{'package':<14}{'lines':>8}{'code':>8}{'share':>8}  layer")
    for pkg, n in code["by_package"].items():
        level = LEVEL.get(pkg)
        print(
            f"{pkg:<14}{lines['by_package'][pkg]:>8}{n:>8}{n / code['total']:>8.1%}  "
            f"{'-' if level is None else level}"
        )
    print(f"sim/ share: {share['lines']:.1%} of lines, {share['code']:.1%} of code lines")
    unlayered = ", ".join(fig["unlayered_packages"]) or "-"
    print(f"top: {', '.join(fig['top_packages']) or '-'}; unlayered: {unlayered}")
    graph = fig["package_imports"]
    print(f"\npackage imports (module level, importer -> imported: imports), {len(graph)} edges:")
    for edge, n in graph.items():
        print(f"  {edge}: {n}")
    for key, title in (
        ("cycles", "cycles (module-level imports)"),
        ("cycles_with_function_imports", "cycles (with imports inside functions)"),
    ):
        c = fig[key]
        comps = "; ".join(", ".join(comp) for comp in c["components"]) or "none"
        print(f"\n{title}: {c['count']}{'+' if c['more'] else ''}; strongly connected: {comps}")
        for cycle in c["list"][:20]:
            print(f"  {cycle}")
        if len(c["list"]) > 20:
            print(f"  ... {len(c['list']) - 20} more")
    for key, title in (
        ("upward_imports", "upward imports (module level)"),
        ("upward_function_imports", "upward imports (inside functions)"),
    ):
        print(f"\n{title}: {len(fig[key])}")
        for up in fig[key]:
            print(f"  {up}")
    for key, title in (
        ("function_imports_outside_cli", "imports inside functions outside cli/ (the tree's modules)"),
        ("function_imports_outside_cli_external", "imports inside functions outside cli/ (other modules)"),
    ):
        print(f"\n{title}: {fig[key]['count']}")
        for item in fig[key]["list"]:
            print(f"  {item}")
    longest = fig["longest_functions"]
    print(f"\n{len(longest)} longest of {fig['functions']} functions (lines, params):")
    for f in longest:
        print(f"  {f['lines']:>5} {f['params']:>4}  {f['name']}")
    many = fig[f"functions_over_{VERY_MANY_PARAMS}_params"]
    print(f"\nfunctions over {VERY_MANY_PARAMS} parameters: {len(many)}")
    for f in many:
        print(f"  {f['params']:>4} {f['lines']:>5}  {f['name']}")
    print(
        f"\nover {LONG_LINES} lines: {fig[f'functions_over_{LONG_LINES}_lines']}; "
        f"over {MANY_PARAMS} parameters: {fig[f'functions_over_{MANY_PARAMS}_params']}"
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=ROOT, help="The package folder (default: src/railstop).")
    parser.add_argument("--json", action="store_true", help="Print the figures as one JSON object.")
    args = parser.parse_args(argv)
    if not (args.root / "__init__.py").is_file():
        print(f"--root: {args.root} is not a package folder (no __init__.py)", file=sys.stderr)
        return 2
    fig = figures(scan(args.root))
    if args.json:
        print(json.dumps(fig, indent=1))
    else:
        _print(fig)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
