"""The structure the README's tour states, checked on the code: no import cycle among the modules
of ``onlinemap`` and ``policies`` (lazy, in-function imports included), every module has a row
in the tour, and imports run one way: a module imports only modules of its own row or of the
rows above it. And the sizes of issue 39: no module over 600 lines, no function with more than 12
positional parameters or over 60 lines (but the files in ``STILL_RESTRUCTURED``).

Imports are read from the source (``ast``), every ``import`` and ``from ... import`` statement
wherever it stands, but those under ``if TYPE_CHECKING:`` (never executed) and a package face's
own lazy re-exports (imports inside an ``__init__.py``'s module ``__getattr__``). An import of
``a.b`` is an edge to the module ``a.b`` only (Python initialises the package ``a`` first, but
that is how packages work, not a dependency of this module on the face's contents); ``from a
import x`` is an edge to the module ``a.x`` when ``x`` is a module, else to ``a`` itself.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("onlinemap", "policies")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def moved(tree: ast.Module) -> bool:
    """A module that only says where it moved: a docstring and ``raise ImportError(...)``."""
    body = [node for node in tree.body if not (isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant))]
    return len(body) == 1 and isinstance(body[0], ast.Raise)


def modules() -> dict[str, Path]:
    """Every module of the packages, but those that only say where they moved."""
    return {module_name(path): path for package in PACKAGES for path in sorted((ROOT / package).rglob("*.py"))
            if not moved(ast.parse(path.read_text()))}


def _type_checking(node: ast.If) -> bool:
    return isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)


def _imports(tree: ast.AST, face: bool):
    """Every import node of ``tree`` but those under ``if TYPE_CHECKING`` and, in a package face,
    inside its ``__getattr__``."""
    for node in ast.iter_child_nodes(tree):
        if _type_checking(node) or (face and isinstance(node, ast.FunctionDef) and node.name == "__getattr__"):
            continue
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        yield from _imports(node, face)


def edges() -> dict[str, set[str]]:
    """module -> the project modules it imports."""
    known = modules()
    graph: dict[str, set[str]] = {name: set() for name in known}
    for name, path in known.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in _imports(ast.parse(path.read_text()), path.name == "__init__.py"):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    base = ".".join(anchor + ([base] if base else []))
                targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base for alias in node.names]
            graph[name] |= {t for t in targets if t in known and t != name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph[node]:
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def tour_rows() -> dict[str, int]:
    """module -> the index of its row in the README's tour (a row names files ``onlinemap/x.py``,
    ``y.py`` (beside the previous name) or folders ``onlinemap/sweeps/``; a module takes the row
    that names it most closely)."""
    text = (ROOT / "README.md").read_text()
    table = text[text.index("## Tour"):]
    table = table.split("\n## ", 1)[0]  # up to the next section, if the tour is not the last
    rows = [line for line in table.splitlines() if line.startswith("| `")]
    named: dict[str, int] = {}
    for number, row in enumerate(rows):
        folder = ""
        for item in re.findall(r"`([^`]+)`", row.split(" | ")[0]):
            path = item if "/" in item else folder + item
            folder = path.rstrip("/").rpartition("/")[0] + "/"  # a bare name after it lies beside it
            named[path] = number
    places = {}
    for name, path in modules().items():
        relative = str(path.relative_to(ROOT))
        candidates = [p for p in named if relative == p or (p.endswith("/") and relative.startswith(p))]
        if candidates:
            places[name] = named[max(candidates, key=len)]
    return places


def test_no_import_cycle_lazy_imports_included():
    found = cycles(edges())
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_the_cycle_check_sees_a_lazy_import():
    """The checker itself: a lazy import back up closes a cycle."""
    graph = {"a": {"b"}, "b": set()}
    assert cycles(graph) == []
    graph["b"].add("a")
    assert cycles(graph) == [["a", "b"]]
    tree = ast.parse("def f():\n    from .x import y\nif TYPE_CHECKING:\n    import z\n")
    assert [ast.unparse(n) for n in _imports(tree, face=False)] == ["from .x import y"]


def test_every_module_has_a_row_in_the_tour():
    rows = tour_rows()
    missing = sorted(set(modules()) - set(rows))
    assert not missing, f"modules the README's tour does not list: {missing}"


def test_imports_run_one_way_down_the_tour():
    rows = tour_rows()
    upward = sorted(f"{a} (row {rows[a]}) imports {b} (row {rows[b]})"
                    for a, targets in edges().items() for b in targets if rows[b] > rows[a])
    assert not upward, "imports against the tour's order:\n" + "\n".join(upward)


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def private_crossings(name: str, source: str, known: set[str]) -> list[str]:
    """The private names module ``name`` (of ``source``) takes from another project module of
    ``known``: ``from M import _x``, and ``A._x`` where ``A`` is bound to a module M by an import
    (``import M as A``, ``from P import M``)."""
    package = name if name in {k.rpartition(".")[0] for k in known if k.startswith(name + ".")} else \
        name.rpartition(".")[0]
    tree = ast.parse(source)
    aliases: dict[str, str] = {}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.asname and alias.name in known:
                    aliases[alias.asname] = alias.name
                elif alias.name.partition(".")[0] in PACKAGES:
                    aliases[alias.name.partition(".")[0]] = alias.name.partition(".")[0]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            if base.partition(".")[0] not in PACKAGES:
                continue
            for alias in node.names:
                if f"{base}.{alias.name}" in known:
                    aliases[alias.asname or alias.name] = f"{base}.{alias.name}"
                elif _private(alias.name) and base != name:
                    found.append(f"{name}: from {base} import {alias.name}")
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _private(node.attr):
            chain, value = [], node.value
            while isinstance(value, ast.Attribute):
                chain.append(value.attr)
                value = value.value
            if isinstance(value, ast.Name) and value.id in aliases:
                owner = ".".join([aliases[value.id]] + chain[::-1])
                if owner != name and owner in known | set(PACKAGES):
                    found.append(f"{name}: {owner}.{node.attr}")
    return found


def test_no_private_name_crosses_a_module():
    known = modules()
    found = [f for name, path in known.items() for f in private_crossings(name, path.read_text(), set(known))]
    assert not found, "private names taken from another module (make them public or move them):\n" + \
        "\n".join(sorted(found))


def test_the_private_name_check_sees_each_spelling():
    known = {"onlinemap", "onlinemap.simulate", "onlinemap.sub", "onlinemap.sub.a", "onlinemap.sub.b"}
    assert private_crossings("onlinemap.sub.a", "from onlinemap.simulate import _categorical, world_step\n",
                             known) == ["onlinemap.sub.a: from onlinemap.simulate import _categorical"]
    assert private_crossings("onlinemap.sub.a", "from .b import _x\n", known) == \
        ["onlinemap.sub.a: from onlinemap.sub.b import _x"]
    assert private_crossings("onlinemap.sub", "from .b import _x\n", known) == \
        ["onlinemap.sub: from onlinemap.sub.b import _x"]
    assert private_crossings("onlinemap.sub.a", "from onlinemap import simulate\nsimulate._categorical(1)\n",
                             known) == ["onlinemap.sub.a: onlinemap.simulate._categorical"]
    assert private_crossings("onlinemap.sub.a", "import onlinemap.simulate as sim\nsim._x\n", known) == \
        ["onlinemap.sub.a: onlinemap.simulate._x"]
    assert private_crossings("onlinemap.sub.a", "import onlinemap\nonlinemap.simulate._x\n", known) == \
        ["onlinemap.sub.a: onlinemap.simulate._x"]
    assert private_crossings("onlinemap.sub.a", "def _own():\n    pass\nself._y = _own()\nx.__len__\n",
                             known) == []
MAX_MODULE_LINES = 600
MAX_POSITIONAL = 12  # keyword-only options (``*, cell_size=None, ...``) do not count: they are named at every call
MAX_FUNCTION_LINES = 60  # from ``def`` to the last line, docstring included, decorators not
#: Files still being restructured by other work, exempt from the limits below until that work
#: lands (none now). A pattern that no longer matches a file over a limit fails
#: ``test_the_size_allow_list_names_only_files_over_a_limit``, so the list cannot outlive its reason.
STILL_RESTRUCTURED: tuple[str, ...] = ()


def positional_parameters(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Parameters a caller may pass by position (``self`` included; ``*args`` and keyword-only not)."""
    return len(node.args.posonlyargs) + len(node.args.args)


def function_lines(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Lines from the ``def`` to the function's last line (docstring included, decorators not)."""
    return node.end_lineno - node.lineno + 1


def size_offences(sources: dict[str, str]) -> dict[str, list[str]]:
    """file (relative to the root) -> what it does over the limits: more than
    :data:`MAX_MODULE_LINES` lines, functions (nested ones and methods included) with more than
    :data:`MAX_POSITIONAL` positional parameters or more than :data:`MAX_FUNCTION_LINES` lines."""
    found: dict[str, list[str]] = {}
    for relative, text in sources.items():
        lines = len(text.splitlines())
        offences = [f"{lines} lines"] if lines > MAX_MODULE_LINES else []
        functions = [node for node in ast.walk(ast.parse(text))
                     if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))]
        offences += [f"{node.name} (line {node.lineno}) takes {positional_parameters(node)} positional parameters"
                     for node in functions if positional_parameters(node) > MAX_POSITIONAL]
        offences += [f"{node.name} (line {node.lineno}) has {function_lines(node)} lines"
                     for node in functions if function_lines(node) > MAX_FUNCTION_LINES]
        if offences:
            found[relative] = offences
    return found


def _sources() -> dict[str, str]:
    return {str(path.relative_to(ROOT)): path.read_text() for path in modules().values()}


def _still_restructured(relative: str) -> bool:
    return any(Path(relative).match(pattern) for pattern in STILL_RESTRUCTURED)


def test_the_size_check_sees_a_long_module_and_a_long_signature():
    """The checker itself: 13 positional parameters and 601 lines are caught; 12, keyword-only
    options and ``*args`` are not."""
    fine = "def f(a, b, c, d, e, f, g, h, i, j, k, l, *rest, m=1, n=2, o=3):\n    pass\n"
    assert size_offences({"fine.py": fine}) == {}
    crowded = "class A:\n    def f(self, a, b, c, d, e, f, g, h, i, j, k, l):\n        pass\n"
    assert size_offences({"crowded.py": crowded}) == {"crowded.py": ["f (line 2) takes 13 positional parameters"]}
    assert size_offences({"long.py": "x = 1\n" * 601}) == {"long.py": ["601 lines"]}
    assert size_offences({"edge.py": "x = 1\n" * 600}) == {}


def test_the_size_check_sees_a_long_function():
    """The checker itself: a function of 61 lines (``def`` to its last line) is caught, one of 60
    is not, its decorator not counted; a nested function counts on its own as well."""
    def function(name: str, body_lines: int, indent: str = "") -> str:
        return f"{indent}@decorated\n{indent}def {name}():\n" + f"{indent}    x = 1\n" * body_lines

    assert size_offences({"fine.py": function("f", 59)}) == {}
    assert size_offences({"long.py": function("f", 60)}) == {"long.py": ["f (line 2) has 61 lines"]}
    nested = "def outer():\n" + function("inner", 60, indent="    ")
    assert size_offences({"nested.py": nested}) == {"nested.py": ["outer (line 1) has 63 lines",
                                                                  "inner (line 3) has 61 lines"]}


def test_no_module_over_600_lines_and_no_function_over_12_positional_parameters_or_60_lines():
    found = {relative: offences for relative, offences in size_offences(_sources()).items()
             if not _still_restructured(relative)}
    assert not found, "over the size limits (split the module or the function into named steps; bundle arrays " \
        "in a NamedTuple or make options keyword-only):\n" + "\n".join(f"{relative}: {'; '.join(offences)}" for relative, offences in found.items())


def test_the_size_allow_list_names_only_files_over_a_limit():
    offending = size_offences(_sources())
    stale = [pattern for pattern in STILL_RESTRUCTURED if not any(Path(relative).match(pattern) for relative in offending)]
    assert not stale, f"STILL_RESTRUCTURED names files now within the limits; remove: {stale}"
