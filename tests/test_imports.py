"""The package's import graph: module-level imports among racing_env, agents and experiments
form no cycle, and the layers import downwards only (racing_env <- agents <- experiments)."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("racing_env", "agents", "experiments")
LAYER = {"racing_env": 0, "agents": 1, "experiments": 2}


def _modules() -> dict:
    """Module name -> source path of every module of the three packages."""
    mods = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join(parts)] = path
    return mods


def _is_type_checking(node) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(tree, lazy: bool):
    """Import nodes run when the module is imported: module level, also inside ``if``/``try``
    blocks, never under ``if TYPE_CHECKING:``; with ``lazy`` also those inside functions and
    classes (run on first use)."""
    todo = list(tree.body)
    while todo:
        node = todo.pop(0)
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif isinstance(node, ast.If) and _is_type_checking(node):
            continue
        elif isinstance(node, (ast.If, ast.Try, ast.With, ast.For, ast.While)) or (
            lazy and isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
        ):
            todo += [
                c
                for c in ast.iter_child_nodes(node)
                if isinstance(c, (ast.stmt, ast.ExceptHandler))
            ]
        elif isinstance(node, ast.ExceptHandler):
            todo += node.body


def import_graph(lazy: bool = False) -> dict:
    """Module -> the package modules its imports load (a package's ``__init__`` when the
    package itself is named): module-level imports, with ``lazy`` also those in functions."""
    mods = _modules()
    graph = {}
    for name, path in mods.items():
        pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
        deps = set()
        for node in _imports(ast.parse(path.read_text(), str(path)), lazy):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                base = node.module or ""
                if node.level:
                    anchor = pkg.split(".")
                    anchor = anchor[: len(anchor) - (node.level - 1)]
                    base = ".".join(anchor + ([base] if base else []))
                targets = [
                    f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names
                ]
            deps |= {t for t in targets if t in mods and t != name}
        graph[name] = deps
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


def test_the_import_graph_is_read():
    graph = import_graph()
    assert {"racing_env.track", "agents.features", "experiments.train"} <= set(graph)
    assert "experiments.nets" in graph["experiments.train"]
    assert "agents.features" in graph["agents.general_features"]


def test_no_import_cycle_among_the_package_modules():
    assert _cycle(import_graph()) is None, " -> ".join(_cycle(import_graph()))


# lazy imports that close a cycle, each until the module that needs it moves on
ALLOWED_LAZY = {
    # agents.features forwards feature_set & co. to agents.feature_sets on first use (a
    # module-level __getattr__ kept for code that imports them from their old place)
    ("agents.features", "agents.feature_sets"),
    # the one import up the layers (an opponent spec string is built by the agents registry
    # when an env is made, never at import): agents.observations re-exports gym_env helpers
    ("racing_env.gym_env", "agents"),
}


def test_no_import_cycle_counting_the_imports_inside_functions():
    graph = import_graph(lazy=True)
    for a, b in ALLOWED_LAZY:
        assert b in graph[a], f"{a} no longer imports {b}: drop it from ALLOWED_LAZY"
        graph[a] = graph[a] - {b}
    assert _cycle(graph) is None, " -> ".join(_cycle(graph))


def test_a_cycle_would_be_found():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]


def test_the_former_cycles_stay_broken():
    graph = import_graph()
    # both trainings import the shared module, neither the other
    assert "experiments.nets" in graph["experiments.train_general"]
    assert "experiments.train" not in graph["experiments.train_general"]
    # the feature-set choice imports both feature modules; they do not import it
    assert {"agents.features", "agents.general_features"} <= graph["agents.feature_sets"]
    assert "agents.general_features" not in graph["agents.features"]
    assert "agents.feature_sets" not in graph["agents.features"]


def _upwards(graph) -> set:
    return {
        (m, d)
        for m, deps in graph.items()
        for d in deps
        if LAYER[d.split(".")[0]] > LAYER[m.split(".")[0]]
    }


def test_layers_import_downwards_only():
    assert _upwards(import_graph()) == set()
    # the one lazy import back: the Gymnasium env builds its embedded opponents from specs
    assert _upwards(import_graph(lazy=True)) == {("racing_env.gym_env", "agents")}
