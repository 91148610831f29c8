"""The package's import graph has no cycle, counting every import, and the layers import
downwards only (racing_env <- agents <- experiments) but for one documented lazy edge.

The graph
---------
**Nodes**: the modules of ``racing_env``, ``agents`` and ``experiments``, found from their
files (a package is the node of its ``__init__.py``).

**Imports read**: every ``import`` and ``from ... import`` statement of a module, at any depth:
at module level, inside functions, methods and classes, and inside ``if``/``else``, ``try``/
``except``/``else``/``finally``, ``with``, ``for``, ``while`` and ``match`` blocks nested in any
way. Only the body of an ``if TYPE_CHECKING:`` (or ``typing.TYPE_CHECKING``) block is skipped:
it never runs (its ``else`` is read). An import inside a function counts as if it ran at
import: it runs on first use, and a cycle through it is as fragile as any other.

**Edges**: module M -> module T when a statement of M loads T:

* ``import a.b.c`` and ``from a.b.c import x`` load ``a.b.c``; ``from a.b import c`` loads
  ``a.b.c`` when that is a module, else ``a.b`` (``c`` is then a name of ``a/b/__init__.py``).
  Relative imports are resolved against M's package.
* Loading ``a.b.c`` also runs the ``__init__`` of each package above it, so M -> ``a`` and
  M -> ``a.b`` too, **except** for the packages that contain M itself: Python imports those
  before M runs, so reaching them again loads nothing. A package whose ``__init__`` imports
  its modules while they import their siblings is therefore no cycle (``agents/__init__.py``
  imports ``agents.mpc_agent``, which imports ``agents.base``: no edge back to ``agents``).
* A statement that names such a package itself (``import agents``, or ``from agents import
  make_agent`` where ``make_agent`` is no module) does count: it reads from an ``__init__``
  that may not have run to its end.
* A module's edge to itself is dropped.

A **cycle** is any closed path in this graph, of any length. There is no exception list: the
one import up the layers (:func:`racing_env.gym_env.make_opponent` builds an opponent from an
agent spec string with ``import agents`` inside the function) is an edge like any other, and
closes no cycle because no module that ``agents`` loads imports ``racing_env.gym_env``.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("racing_env", "agents", "experiments")
LAYER = {"racing_env": 0, "agents": 1, "experiments": 2}
# the one import up the layers, inside a function (see the module docstring)
UPWARD = {("racing_env.gym_env", "agents")}


def _modules(root: Path = ROOT, packages=PACKAGES) -> dict:
    """Module name -> source path of every module of ``packages`` under ``root``."""
    mods = {}
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join(parts)] = path
    return mods


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(node: ast.AST, lazy: bool = True):
    """``(statement, in_function)`` for every import statement below ``node`` at any depth
    (see the module docstring), but for those under ``if TYPE_CHECKING:``; with ``lazy=False``
    only those that run when the module is imported (none inside a function)."""
    todo = [(node, False)]
    while todo:
        node, in_function = todo.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node, in_function
            continue
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            if not lazy:
                continue
            in_function = True
        children = (
            node.orelse
            if isinstance(node, ast.If) and _is_type_checking(node)
            else list(ast.iter_child_nodes(node))
        )
        todo += [(c, in_function) for c in reversed(children)]


def _parents(name: str) -> list:
    """The packages above module ``name``: ``a.b.c`` -> ``["a", "a.b"]``."""
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def _targets(node, name: str, is_package: bool, mods: dict) -> set:
    """The package modules import statement ``node`` of module ``name`` loads (see the module
    docstring for the rule on parent packages)."""
    if isinstance(node, ast.Import):
        named = {a.name for a in node.names}
    else:
        base = node.module or ""
        if node.level:
            anchor = (name if is_package else name.rpartition(".")[0]).split(".")
            anchor = anchor[: len(anchor) - (node.level - 1)]
            base = ".".join(anchor + ([base] if base else []))
        named = {f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names}
    own = set(_parents(name)) | ({name} if is_package else set())
    loaded = set(named)
    for target in named:
        loaded |= set(_parents(target)) - own
    return {t for t in loaded if t in mods and t != name}


def import_graph(lazy: bool = True, root: Path = ROOT, packages=PACKAGES) -> dict:
    """Module -> the package modules its imports load (see the module docstring); with
    ``lazy=False`` only the imports that run when the module is imported."""
    mods = _modules(root, packages)
    graph = {}
    for name, path in mods.items():
        tree = ast.parse(path.read_text(), str(path))
        is_package = path.name == "__init__.py"
        graph[name] = set().union(
            *(_targets(node, name, is_package, mods) for node, _ in _imports(tree, lazy))
        )
    return graph


def _cycle(graph):
    """One cycle of ``graph`` as a list of modules, or None."""
    state, stack = {}, []

    def visit(v):
        state[v] = 1
        stack.append(v)
        for w in sorted(graph[v]):
            if state.get(w) == 1:
                return stack[stack.index(w) :] + [w]
            if w not in state:
                found = visit(w)
                if found:
                    return found
        stack.pop()
        state[v] = 2
        return None

    for v in sorted(graph):
        if v not in state:
            found = visit(v)
            if found:
                return found
    return None


def test_no_import_cycle_counting_every_import():
    cycle = _cycle(import_graph())
    assert cycle is None, " -> ".join(cycle)


def test_the_import_graph_is_read():
    graph = import_graph()
    mods = _modules()
    assert set(graph) == set(mods)
    for pkg in PACKAGES:
        assert pkg in graph and any(m.startswith(pkg + ".") for m in graph), pkg
    assert "agents.features" in graph["agents.general_features"]
    # a lazy import (inside a function) is read
    assert "racing_env.tracks" in graph["agents.general_features"]
    assert "racing_env.tracks" not in import_graph(lazy=False)["agents.general_features"]
    # importing a module of another package runs that package's __init__
    assert "racing_env" in graph["agents.general_features"]
    # a package's own modules reach their siblings without an edge back to the package
    assert "agents" not in graph["agents.mpc_agent"]


def test_every_kind_of_nesting_is_read(tmp_path):
    (tmp_path / "p").mkdir()
    (tmp_path / "p" / "__init__.py").write_text("from . import a\n")
    (tmp_path / "p" / "a.py").write_text("from .b import x\n")
    (tmp_path / "p" / "b.py").write_text("x = 1\n")
    (tmp_path / "q").mkdir()
    (tmp_path / "q" / "__init__.py").write_text("")
    (tmp_path / "q" / "deep.py").write_text(
        "from typing import TYPE_CHECKING\n"
        "import typing\n"
        "if TYPE_CHECKING:\n    import q.t1\n"
        "elif True:\n    import q.e1\n"
        "if typing.TYPE_CHECKING:\n    import q.t2\n"
        "else:\n    import q.e2\n"
        "class C:\n"
        "    def m(self):\n"
        "        with open('f'):\n"
        "            for i in ():\n"
        "                while i:\n"
        "                    try:\n"
        "                        pass\n"
        "                    except Exception:\n"
        "                        if i:\n"
        "                            import q.m1\n"
        "                    finally:\n"
        "                        match i:\n"
        "                            case 1:\n"
        "                                from .m2 import y\n"
        "async def f():\n"
        "    from p import a\n"
    )
    for n in ("t1", "t2", "e1", "e2", "m1", "m2"):
        (tmp_path / "q" / f"{n}.py").write_text("y = 1\n")
    graph = import_graph(root=tmp_path, packages=("p", "q"))
    assert graph["q.deep"] == {"q.e1", "q.e2", "q.m1", "q.m2", "p.a", "p"}
    assert import_graph(False, tmp_path, ("p", "q"))["q.deep"] == {"q.e1", "q.e2"}
    # a package importing its modules, which import their siblings: no cycle
    assert graph["p"] == {"p.a"} and graph["p.a"] == {"p.b"}
    assert _cycle(graph) is None
    # a module that reads a name from its own package's __init__ closes one
    (tmp_path / "p" / "__init__.py").write_text("from . import a\nname = 1\n")
    (tmp_path / "p" / "b.py").write_text("def g():\n    from p import name\n")
    assert _cycle(import_graph(root=tmp_path, packages=("p", "q"))) == ["p", "p.a", "p.b", "p"]


def test_a_cycle_would_be_found():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]


def test_the_former_cycles_stay_broken():
    graph = import_graph()
    # the feature-set choice imports both feature modules; they do not import it
    assert {"agents.features", "agents.general_features"} <= graph["agents.feature_sets"]
    assert "agents.feature_sets" not in graph["agents.features"]
    assert "agents.feature_sets" not in graph["agents.general_features"]
    assert "agents.general_features" not in graph["agents.features"]
    # the agents layer takes the env-side helpers from a world module that imports no env
    assert "racing_env.gym_env" not in graph["agents.observations"]
    assert not any("agents" in graph[m] for m in graph if m.startswith("agents"))


def _upwards(graph) -> set:
    return {
        (m, d)
        for m, deps in graph.items()
        for d in deps
        if LAYER[d.split(".")[0]] > LAYER[m.split(".")[0]]
    }


def test_layers_import_downwards_only():
    assert _upwards(import_graph(lazy=False)) == set()
    # the one lazy import back: the Gymnasium env builds its embedded opponents from specs
    assert _upwards(import_graph()) == UPWARD


MAX_MODULE_LINES = 600


def test_every_module_is_one_a_reader_can_hold_in_mind():
    """No module of the three packages is over 600 lines (docs/design.md: one job per module)."""
    long = {
        str(path.relative_to(ROOT)): n
        for path in _modules().values()
        if (n := len(path.read_text().splitlines())) > MAX_MODULE_LINES
    }
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"
