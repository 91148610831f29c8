"""The README, the examples and the project files it points to."""

import argparse
import contextlib
import io
import os
import re
import runpy
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
REPO_DIRS = (
    "racing_env",
    "agents",
    "experiments",
    "examples",
    "benchmarks",
    "docs",
    "tests",
    "results",
    ".ci",
)
ROOT_FILES = ("CITATION.cff", "CHANGELOG.md", "pyproject.toml", "mkdocs.yml", "README.md")
# outputs of the commands the README shows, not files of the repository
GENERATED = (
    "results/race",
    "results/ibr_race",
    "results/raceline",
    "results/bench",
    "results/example",
    "results/paper_table_mpc_ego",
    "results/paper_table/runs.jsonl",
    "results/policy_map",
    "results/league",
    "results/general",
    "agents/models/alpha_general.npz",
    "results/control",
    "results/paper_table_control",
    "results/comparison.md",
    "results/analysis",
    "results/strategy",
)


def _readme_paths() -> set[str]:
    paths = set()
    for target in re.findall(r"\]\(([^)\s]+)\)", README):  # [text](target), ![..](..)
        if not re.match(r"[a-z]+:|#", target):
            paths.add(target.split("#")[0])
    for token in re.split(r"[\s`'\"(),\[\]]+", README):
        token = token.split("::")[0].split("#")[0].rstrip(".:;")
        if token.startswith(tuple(d + "/" for d in REPO_DIRS)) or token in ROOT_FILES:
            paths.add(token)
    return paths


def _heading_slugs(page: str) -> set[str]:
    """The anchors MkDocs gives a page's headings (the toc extension's own ``slugify``, on the
    heading's text without its code marks)."""
    from markdown.extensions.toc import slugify

    headings = re.findall(r"^#{1,6} (.+?)\s*$", page, re.M)
    return {slugify(heading.replace("`", ""), "-") for heading in headings}


def test_readme_anchors_name_headings_of_their_pages():
    links = re.findall(r"\]\((docs/[^)\s#]+\.md)#([^)\s]+)\)", README)
    assert links, "the README links to sections of the docs"
    bad = [
        f"{page}#{anchor}"
        for page, anchor in links
        if anchor not in _heading_slugs((ROOT / page).read_text())
    ]
    assert not bad, f"README links to sections that do not exist: {bad}"


def test_readme_points_only_inside_the_repository():
    assert "../" not in README
    paths = _readme_paths()
    assert {"docs/design.md", "examples/bench_api.py", "CITATION.cff", "CHANGELOG.md"} <= paths
    shipped = (
        GENERATED if (ROOT / "results").is_dir() else (*GENERATED, "results/")
    )  # sdist: no results/
    missing = sorted(
        p for p in paths if not p.startswith(shipped) and not any(ROOT.glob(p.rstrip("/")))
    )  # globs: case_*/
    assert not missing, f"README names paths that are not in the repository: {missing}"


def test_bench_api_example_runs(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["bench_api.py", str(tmp_path)])
    runpy.run_path(str(ROOT / "examples" / "bench_api.py"), run_name="__main__")
    text = capsys.readouterr().out
    assert "progress m" in text and "# Benchmark: `mpc` vs two `raceline`" in text
    assert (tmp_path / "race" / "race.gif").exists()
    assert (tmp_path / "race" / "result.json").exists()
    assert len((tmp_path / "bench" / "races.jsonl").read_text().splitlines()) == 3


def test_citation_names_the_paper_and_its_authors():
    yaml = pytest.importorskip("yaml")
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    paper = cff["preferred-citation"]
    assert "alpha-RACER" in paper["title"] and paper["year"] == 2025
    assert [a["family-names"] for a in paper["authors"]] == ["Kalaria", "Maheshwari", "Sastry"]
    assert "L4DC" in paper["conference"]["name"]


def test_changelog_follows_keep_a_changelog():
    text = (ROOT / "CHANGELOG.md").read_text()
    assert "keepachangelog.com" in text and "## [Unreleased]" in text
    assert re.search(r"^## \[\d+\.\d+\.\d+\] - \d{4}-\d{2}-\d{2}$", text, re.M)


def test_docs_pages_and_pictures_exist():
    yaml = pytest.importorskip("yaml")
    nav = yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"]

    def pages(item):
        if isinstance(item, str):
            yield item
        elif isinstance(item, list):
            for x in item:
                yield from pages(x)
        else:
            for x in item.values():
                yield from pages(x)

    for page in pages(nav):
        assert (ROOT / "docs" / page).exists(), page
    for page in (ROOT / "docs").rglob("*.md"):
        for img in re.findall(r"!\[[^]]*\]\(([^)]+)\)", page.read_text()):
            assert (page.parent / img).resolve().exists(), f"{page}: {img}"


# ---------------------------------------------------------------------- commands quoted in the docs
DOC_FILES = [ROOT / "README.md"] + sorted((ROOT / "docs").rglob("*.md"))


def quoted_commands(text: str) -> list[str]:
    """Every ``alpha-racer ...`` command of a Markdown text: the lines of its shell code blocks
    (backslash continuations joined, comments dropped, ``&&`` chains split) and its inline code."""
    commands = []
    blocks = re.findall(r"^[ \t]*```(\w*)[^\n]*\n(.*?)^[ \t]*```", text, re.S | re.M)
    for lang, body in blocks:
        if lang not in ("", "bash", "sh", "shell", "console"):
            continue
        for line in re.sub(r"\\\n\s*", " ", body).splitlines():
            for part in re.split(r"&&|;", line.split(" #")[0]):
                if part.strip().startswith("alpha-racer "):
                    commands.append(" ".join(part.split()))
    prose = re.sub(r"^[ \t]*```.*?^[ \t]*```", "", text, flags=re.S | re.M)
    for span in re.findall(r"`([^`\n]+)`", prose):
        for part in re.split(r"&&|;", span):
            if part.strip().startswith("alpha-racer "):
                commands.append(" ".join(part.split()))
    return commands


def test_quoted_commands_are_found():
    text = (
        "Run `alpha-racer race --steps 100` or\n\n```bash\nalpha-racer bench --ego alpha \\\n"
        "    --opponents ibr   # a comment\npip install -e . && alpha-racer tracks\n```\n"
        "```python\nalpha-racer = 1\n```\n"
    )
    assert quoted_commands(text) == [
        "alpha-racer bench --ego alpha --opponents ibr",
        "alpha-racer tracks",
        "alpha-racer race --steps 100",
    ]


def test_every_quoted_command_parses_with_the_current_cli():
    from experiments.cli import build_parser

    parser = build_parser()
    subcommands = next(
        a for a in parser._actions if isinstance(a, argparse._SubParsersAction)
    ).choices
    found, bad = 0, []
    for path in DOC_FILES:
        for command in quoted_commands(path.read_text()):
            # placeholders of the prose: [optional parts], "...", COMMAND
            argv = [
                t
                for t in shlex.split(command.replace("[", " ").replace("]", " "))[1:]
                if t != "..."
            ]
            if not argv or argv[0] == "COMMAND":
                continue
            found += 1
            if argv[0] not in subcommands:
                bad.append(f"{path.relative_to(ROOT)}: {command!r}: no command {argv[0]!r}")
                continue
            if len(argv) == 1:  # the command named in prose: its name suffices
                continue
            err = io.StringIO()
            try:
                with contextlib.redirect_stderr(err):
                    parser.parse_args(argv)
            except SystemExit:
                bad.append(
                    f"{path.relative_to(ROOT)}: {command!r}: {err.getvalue().strip().splitlines()[-1]}"
                )
    assert found > 50, f"only {found} commands found: is the extraction broken?"
    assert not bad, "commands in the docs that the CLI refuses:\n" + "\n".join(bad)


# ---------------------------------------------------------------------- the README's first examples
def test_readme_python_examples_run(monkeypatch, tmp_path):
    """The README's Python blocks (the PettingZoo and the Gymnasium examples) run as printed."""
    monkeypatch.chdir(tmp_path)
    blocks = re.findall(r"^```python\n(.*?)^```", README, re.S | re.M)
    assert len(blocks) >= 2
    for code in blocks:
        exec(compile(code, "README.md", "exec"), {"__name__": "readme_example"})


# ---------------------------------------------------------------------- the built site
def test_built_site_has_no_literal_sphinx_roles(tmp_path):
    """The API reference renders the docstrings' Sphinx roles as links or code (about 6 s)."""
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    site = tmp_path / "site"
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    run = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "--site-dir", str(site)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    role = re.compile(r":(?:py:)?(?:class|func|meth|data|mod|attr|exc|obj|const):(?:<code>|`)")
    pages = list(site.rglob("*.html"))
    assert len(pages) > 10
    literal = {str(p.relative_to(site)): role.findall(p.read_text())[:3] for p in pages}
    literal = {k: v for k, v in literal.items() if v}
    assert not literal, f"literal Sphinx roles in the built site: {literal}"
    api = (site / "api" / "racing_env" / "index.html").read_text()
    assert 'class="autorefs autorefs-internal"' in api  # roles became links


def test_sphinx_roles_become_optional_cross_references():
    griffe = pytest.importorskip("griffe")
    hooks = runpy.run_path(str(ROOT / "docs" / "hooks.py"))
    module = griffe.Module("m")
    text = "See :class:`~racing_env.track.Track`, :func:`make <racing_env.make_track>` and :mod:`agents`."
    out = hooks["replace_roles"](text, module)
    assert ":class:" not in out and ":func:" not in out and ":mod:" not in out
    assert (
        '<autoref identifier="racing_env.track.Track" optional><code>Track</code></autoref>' in out
    )
    assert '<autoref identifier="racing_env.make_track" optional><code>make</code></autoref>' in out
