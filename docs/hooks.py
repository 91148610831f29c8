"""Build-time helpers of the docs site (not part of the package, not a page).

``SphinxRoles`` is a griffe extension (``extensions`` of the mkdocstrings Python handler in
``mkdocs.yml``). The package's docstrings use Sphinx roles (``:class:`racing_env.Track```,
``:func:`~racing_env.tracks.make_track```, ``:meth:`reset```), which mkdocstrings would show as
literal text. After griffe has loaded a package, every role in every docstring becomes an
*optional* mkdocs-autorefs cross-reference:

* the target is resolved in the scope of the object whose docstring holds it (so ``:meth:`reset```
  in a class docstring points at that class's ``reset``, ``:class:`RaceConfig``` at what the module
  imported under that name); a dotted name whose head is not in scope is taken as absolute;
* the reference is a link where the target is documented on the site, and plain code where it is
  not: ``optional`` references never fail ``mkdocs build --strict``;
* ``~a.b.c`` shows ``c``, ``Title <a.b.c>`` shows ``Title``, anything else shows the name as written.

The package's source files are not changed.
"""

from __future__ import annotations

import html
import re
from typing import Any

import griffe

ROLE_RE = re.compile(
    r":(?:py:)?(?P<role>class|func|meth|data|mod|attr|exc|obj|const|type):`(?P<body>[^`]+)`"
)


def _target_and_title(body: str) -> tuple[str, str]:
    body = body.strip()
    titled = re.fullmatch(r"(?P<title>.+?)\s*<(?P<target>[^<>]+)>", body)
    if titled:
        return titled["target"].strip().lstrip("~!"), titled["title"].strip()
    target = body.lstrip("!")
    if target.startswith("~"):
        target = target[1:]
        return target, target.rsplit(".", 1)[-1]
    return target, target


def _resolve(obj: griffe.Object, target: str) -> str:
    """The full path of ``target`` as seen from ``obj``'s scope; ``target`` itself if unknown."""
    name = target[:-2] if target.endswith("()") else target
    if name.startswith("."):
        name = name.lstrip(".")
    head, _, rest = name.partition(".")
    scopes = [obj] if obj.is_class or obj.is_module else []
    scopes += [p for p in (obj.parent, obj.module) if p is not None]
    for scope in scopes:
        try:
            full = scope.resolve(head)
        except Exception:  # griffe.NameResolutionError, or an alias that cannot resolve
            continue
        return f"{full}.{rest}" if rest else full
    return name


def replace_roles(text: str, obj: griffe.Object) -> str:
    """``text`` with every Sphinx role turned into an optional autorefs reference."""

    def sub(match: re.Match) -> str:
        target, title = _target_and_title(match["body"])
        identifier = _resolve(obj, target)
        return (
            f'<autoref identifier="{html.escape(identifier, quote=True)}" optional>'
            f"<code>{html.escape(title)}</code></autoref>"
        )

    return ROLE_RE.sub(sub, text)


def _walk(obj: griffe.Object, seen: set[int]):
    if id(obj) in seen:
        return
    seen.add(id(obj))
    yield obj
    for member in obj.members.values():
        if member.is_alias:
            continue
        yield from _walk(member, seen)


class SphinxRoles(griffe.Extension):
    """Rewrite Sphinx roles in docstrings into optional mkdocs-autorefs cross-references."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        for obj in _walk(pkg, set()):
            if obj.docstring is not None and ":" in obj.docstring.value:
                obj.docstring.value = replace_roles(obj.docstring.value, obj)
