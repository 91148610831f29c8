"""The public API of racing_env and agents is annotated: every public function and method (a
name without a leading underscore, in a module without one) of their modules has an annotation
on each parameter (``self``, ``cls``, ``*args`` and ``**kwargs`` aside) and on its return."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

PACKAGES = ("racing_env", "agents")

# (module, qualified name) -> why it cannot be annotated
EXCEPTIONS: dict[tuple[str, str], str] = {
    (
        "racing_env.vehicle",
        "frenet_ode_numpy",
    ): "frenet_ode rebound to numpy by vehicle.bind (types.FunctionType of its code object): a "
    "function built at import carries no annotations; frenet_ode itself is annotated",
}


def public_modules() -> list[str]:
    """The importable public modules of the two packages (an optional dependency missing skips
    the module, as its tests are skipped)."""
    names = []
    for pkg in PACKAGES:
        names.append(pkg)
        mod = importlib.import_module(pkg)
        for info in pkgutil.walk_packages(mod.__path__, pkg + "."):
            if any(part.startswith("_") for part in info.name.split(".")):
                continue
            names.append(info.name)
    return names


def _functions(mod):
    """(qualified name, function) of the public functions and methods defined in ``mod``."""
    for name, obj in vars(mod).items():
        if name.startswith("_") or getattr(obj, "__module__", None) != mod.__name__:
            continue
        if inspect.isfunction(obj):
            yield name, obj
        elif inspect.isclass(obj):
            for attr, member in vars(obj).items():
                if attr.startswith("_"):
                    continue
                if isinstance(member, (staticmethod, classmethod)):
                    member = member.__func__
                elif isinstance(member, property):
                    member = member.fget
                if inspect.isfunction(member) and member.__module__ == mod.__name__:
                    yield f"{name}.{attr}", member


def missing_annotations(func) -> list[str]:
    """The parameters of ``func`` without an annotation, and ``return`` when it has none."""
    sig = inspect.signature(func, follow_wrapped=False)
    params = list(sig.parameters.values())
    missing = [
        p.name
        for i, p in enumerate(params)
        if p.annotation is inspect.Parameter.empty
        and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
        and not (i == 0 and p.name in ("self", "cls"))
    ]
    if sig.return_annotation is inspect.Signature.empty:
        missing.append("return")
    return missing


def test_the_public_api_is_annotated():
    problems = []
    seen = 0
    for modname in public_modules():
        try:
            mod = importlib.import_module(modname)
        except ImportError as err:  # an optional dependency (torch, casadi) is not installed
            if getattr(err, "name", None) and err.name.split(".")[0] in PACKAGES:
                raise
            continue
        for qualname, func in _functions(mod):
            seen += 1
            if (modname, qualname) in EXCEPTIONS:
                continue
            missing = missing_annotations(func)
            if missing:
                problems.append(f"{modname}.{qualname}: {', '.join(missing)}")
    assert seen > 100
    assert not problems, "unannotated:\n" + "\n".join(problems)


@pytest.mark.parametrize("key", sorted(EXCEPTIONS))
def test_each_exception_names_a_public_function(key):
    modname, qualname = key
    obj = importlib.import_module(modname)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    assert callable(obj) or isinstance(obj, property)
