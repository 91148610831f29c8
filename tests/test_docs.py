"""The README, the examples and the project files it points to."""
import re
import runpy
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
REPO_DIRS = ("racing_env", "agents", "experiments", "examples", "benchmarks", "docs", "tests",
             "results", ".ci")
ROOT_FILES = ("CITATION.cff", "CHANGELOG.md", "pyproject.toml", "mkdocs.yml", "README.md")
# outputs of the commands the README shows, not files of the repository
GENERATED = ("results/race", "results/ibr_race", "results/raceline", "results/bench", "results/example",
             "results/paper_table_mpc_ego", "results/paper_table/runs.jsonl", "results/policy_map",
             "results/league", "results/general", "agents/models/alpha_general.npz",
             "results/control", "results/paper_table_control", "results/comparison.md",
             "results/analysis", "results/strategy")


def _readme_paths() -> set[str]:
    paths = set()
    for target in re.findall(r"\]\(([^)\s]+)\)", README):           # [text](target), ![..](..)
        if not re.match(r"[a-z]+:|#", target):
            paths.add(target.split("#")[0])
    for token in re.split(r"[\s`'\"(),\[\]]+", README):
        token = token.split("::")[0].rstrip(".:;")
        if token.startswith(tuple(d + "/" for d in REPO_DIRS)) or token in ROOT_FILES:
            paths.add(token)
    return paths


def test_readme_points_only_inside_the_repository():
    assert "../" not in README
    paths = _readme_paths()
    assert {"docs/design.md", "examples/bench_api.py", "CITATION.cff", "CHANGELOG.md"} <= paths
    shipped = GENERATED if (ROOT / "results").is_dir() else (*GENERATED, "results/")  # sdist: no results/
    missing = sorted(p for p in paths if not p.startswith(shipped)
                     and not any(ROOT.glob(p.rstrip("/"))))          # globs: case_*/
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
