"""Runs record what made them (package version, commit, hashes of the model files their agents
load); a resume with other weights is refused, another version is flagged; agents join a
finished league and only their races run."""

import json
import shutil
import warnings

import pytest

from experiments.evaluation import leaderboard as lb
from experiments.evaluation import league as lg
from experiments.evaluation import league_schedule as ls
from experiments.evaluation.bench import bench
from experiments.evaluation.bench_config import BenchConfig
from experiments.infra import artifacts
from experiments.infra.artifacts import read_jsonl
from experiments.infra.parallel import Pool

pytest.importorskip("stable_baselines3")


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    """A copy of the shipped PPO checkpoint, a file the test may overwrite."""
    from agents.ppo_agent import default_checkpoint

    path = tmp_path_factory.mktemp("ckpt") / "mine.zip"
    shutil.copy(default_checkpoint(), path)
    return path


def test_manifests_record_version_commit_and_model_hashes(tmp_path, checkpoint):
    import racing_env
    from agents.potential import MODEL_DIR, SHIPPED

    prov = artifacts.provenance([f"ppo:checkpoint={checkpoint}", "alpha:model=general", "raceline"])
    assert prov["package_version"] == racing_env.__version__
    commit = prov["git_commit"]
    assert commit is None or len(commit.split("+")[0]) == 40
    files = prov["model_files"]
    assert set(files) == {f"ppo:checkpoint={checkpoint}", "alpha:model=general"}
    assert files[f"ppo:checkpoint={checkpoint}"] == {
        str(checkpoint.resolve()): artifacts.sha256_file(checkpoint)
    }
    assert list(files["alpha:model=general"]) == [str((MODEL_DIR / SHIPPED["general"]).resolve())]
    auto = artifacts.agent_model_files("alpha")  # model=auto: both candidates
    assert {p.name for p in auto} == {SHIPPED["default"], SHIPPED["general"]}


def test_a_model_of_a_space_without_shipped_models_is_recorded(tmp_path):
    """An alpha agent racing its own model of the wake space (which ships no model for
    ``model=auto``) records that file, instead of failing to list the space's auto models."""
    from types import SimpleNamespace

    model = tmp_path / "model.npz"
    model.write_bytes(b"weights")
    agent = SimpleNamespace(model_name=str(model), space="wake")
    assert artifacts.agent_model_files(f"alpha:model={model}", agent) == [model]
    auto = SimpleNamespace(model_name="auto", space="wake")
    assert artifacts.agent_model_files("alpha", auto) == []


def _bench_config(checkpoint):
    return BenchConfig(ego=f"ppo:checkpoint={checkpoint}", opponents="raceline", races=3, steps=5)


def test_resumed_bench_with_a_changed_checkpoint_is_refused(tmp_path, checkpoint):
    out = tmp_path / "bench"
    cfg = _bench_config(checkpoint)
    bench(cfg, out, pool=Pool(workers=1, progress_bar=False))
    lines = (out / "races.jsonl").read_text().splitlines(keepends=True)
    (out / "races.jsonl").write_text("".join(lines[:1]))  # killed after one race
    manifest = json.loads((out / "manifest.json").read_text())
    prov = manifest["provenance"]
    assert prov["model_files"][cfg.ego] == {
        str(checkpoint.resolve()): artifacts.sha256_file(checkpoint)
    }
    original = checkpoint.read_bytes()
    try:
        from agents.ppo_agent import load_ppo, read_checkpoint_meta, save_checkpoint

        model = load_ppo(checkpoint)
        for p in model.policy.parameters():  # other weights, same format
            p.data.mul_(0.5)
        save_checkpoint(model, None, checkpoint, read_checkpoint_meta(checkpoint))
        before = (out / "races.jsonl").read_text()
        with pytest.raises(
            ValueError,
            match=r"raced with other weights.*ppo:checkpoint=.*mine\.zip.*"
            r"was sha256 [0-9a-f]{12}\.\.\., now [0-9a-f]{12}",
        ):
            bench(cfg, out, pool=Pool(workers=1, progress_bar=False))
        assert (out / "races.jsonl").read_text() == before  # nothing raced
    finally:
        checkpoint.write_bytes(original)
    summary = bench(cfg, out, pool=Pool(workers=1, progress_bar=False))  # the same weights: resumes
    assert len(read_jsonl(out / "races.jsonl")) == 3 and summary


def test_a_changed_version_or_commit_is_warned_about_naming_both(tmp_path):
    stored = {"package_version": "0.0.9", "git_commit": "a" * 40, "model_files": {}}
    now = {"package_version": "0.1.0", "git_commit": "b" * 40, "model_files": {}}
    with pytest.warns(
        RuntimeWarning,
        match=r"alpha-racer 0\.0\.9 \(commit a{40}\) with alpha-racer "
        r"0\.1\.0 \(commit b{40}\)",
    ):
        merged = artifacts.check_provenance(stored, now, tmp_path, "a benchmark")
    assert merged["package_version"] == "0.0.9"
    assert merged["resumed_with"] == [{"package_version": "0.1.0", "git_commit": "b" * 40}]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert artifacts.check_provenance(stored, dict(stored), tmp_path, "x") == stored


def test_collect_manifest_records_provenance(tmp_path):
    from experiments.potential.collect import CollectConfig, collect

    cfg = CollectConfig(races=1, steps=3)
    collect(cfg, tmp_path / "c", pool=Pool(workers=1, progress_bar=False))
    prov = json.loads((tmp_path / "c" / "manifest.json").read_text())["provenance"]
    assert prov["model_files"] == {} and "package_version" in prov and "git_commit" in prov


# ---------------------------------------------------------------------------- league join
BASE = ("raceline", "raceline:grip=0.6", "raceline:speed_scale=0.7")
NEW = "raceline:line_fraction=0.5"
CFG = ls.LeagueConfig(agents=BASE, tracks=("oval",), cars=2, steps=20, seed=1)


def test_schedule_of_one_stage_is_unchanged_and_a_join_adds_only_new_groups():
    full = ls.LeagueConfig(**{**CFG.__dict__, "agents": BASE + (NEW,)})
    first = ls.schedule(CFG)
    joined = ls.schedule(full, [3, 4])
    assert joined[: len(first)] == first
    added = joined[len(first) :]
    assert added and all(NEW in r.agents for r in added)
    assert {r.agents for r in added} == {
        tuple(sorted((a, NEW), key=full.agents.index)) for a in BASE
    }
    assert [r.index for r in joined] == list(range(len(joined)))
    with pytest.raises(ValueError, match="stages must grow"):
        ls.schedule(full, [4, 3])


def test_an_agent_joins_a_finished_league_and_only_its_races_run(tmp_path):
    out = tmp_path / "league"
    board = lg.league(CFG, out, pool=Pool(workers=1, progress_bar=False))
    n_before = len(read_jsonl(out / "races.jsonl"))
    full = ls.LeagueConfig(**{**CFG.__dict__, "agents": BASE + (NEW,)})
    joined = lg.league(full, out, pool=Pool(workers=1, progress_bar=False))
    records = read_jsonl(out / "races.jsonl")
    new = records[n_before:]
    assert joined["new_races"] == len(new) == 3 * CFG.cars  # 3 new pairs x 2 rotations
    assert all(NEW in r["agents"] for r in new)
    assert {row["agent"] for row in joined["standings"]} == set(full.agents)
    assert sum(row["races"] for row in joined["standings"]) == CFG.cars * len(records)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["stages"] == [3, 4] and manifest["config"]["agents"] == list(full.agents)
    assert lg.league(full, out, pool=Pool(workers=1, progress_bar=False))["new_races"] == 0
    # the ratings are a replay over all races, in race order
    replay = lb.rate(sorted(records, key=lambda r: r["race"]), full.agents)
    for row in joined["standings"]:
        assert row["mu"] == pytest.approx(replay[row["agent"]][0])
    assert board["standings"]
    with pytest.raises(ValueError, match="another configuration"):  # other settings: refused
        lg.league(
            ls.LeagueConfig(
                **{**full.__dict__, "agents": BASE + (NEW, "raceline:grip=0.7"), "steps": 21}
            ),
            out,
            pool=Pool(workers=1, progress_bar=False),
        )
