"""Head-to-head benchmark: the paper's protocol, statistics, output invariants, resume."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("daqp")

from experiments.cli import main  # noqa: E402
from experiments.evaluation.bench import BenchRun, bench, bench_race
from experiments.evaluation.bench_config import BenchConfig
from experiments.evaluation.bench_summary import summarise, wilson_interval
from experiments.evaluation.paper_table import PAPER_CASES, paper_cases
from experiments.infra.parallel import Pool

TINY = BenchConfig(ego="mpc:zeta=0.95", opponents="raceline", races=4, steps=15, seed=3)


# ---------------------------------------------------------------------------- statistics
def test_wilson_interval_hand_derived_cases():
    # 0 of n: lower 0, upper z^2 / (n + z^2)
    z2 = 1.959964**2
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(z2 / (10 + z2), rel=1e-9)
    # n of n mirrors it
    lo, hi = wilson_interval(10, 10)
    assert hi == 1.0 and lo == pytest.approx(10 / (10 + z2), rel=1e-9)
    # 50 of 100: centre 0.5, half width z sqrt(1/400 + z^2/40000) / (1 + z^2/100)
    lo, hi = wilson_interval(50, 100)
    half = 1.959964 * np.sqrt(0.25 / 100 + z2 / 40000) / (1 + z2 / 100)
    assert (lo, hi) == pytest.approx((0.5 - half, 0.5 + half), rel=1e-9)


@settings(max_examples=200, deadline=None)
@given(n=st.integers(1, 500), frac=st.floats(0, 1))
def test_wilson_interval_contains_the_estimate_and_stays_in_0_1(n, frac):
    w = int(round(frac * n))
    lo, hi = wilson_interval(w, n)
    assert 0.0 <= lo <= w / n <= hi <= 1.0


def test_wilson_interval_refuses_bad_counts():
    with pytest.raises(ValueError, match="n >= 1"):
        wilson_interval(0, 0)
    with pytest.raises(ValueError, match=r"wins must be in \[0, n=5\], got 6"):
        wilson_interval(6, 5)


# ---------------------------------------------------------------------------- protocol
def test_start_order_follows_the_paper_protocol():
    orders = [BenchConfig.start_order(k) for k in range(99)]
    assert all(sorted(o) == [0, 1, 2] for o in orders)
    assert [sum(o[0] == r for o in orders) for r in range(3)] == [33, 33, 33]
    assert all(o[1] < o[2] for o in orders)  # O1 always ahead of O2


def test_start_order_scaled_to_n_cars():
    """N start regions: the ego from each equally often, the opponents front to back in the
    others; N = 3 is the paper's order, race for race."""
    assert [BenchConfig.start_order(k) for k in range(3)] == [[0, 1, 2], [1, 0, 2], [2, 0, 1]]
    for n in range(2, 9):
        orders = [BenchConfig.start_order(k, n) for k in range(4 * n)]
        assert all(sorted(o) == list(range(n)) for o in orders)
        assert [sum(o[0] == r for o in orders) for r in range(n)] == [4] * n
        assert all(o[1:] == sorted(o[1:]) for o in orders)
        assert [o[0] for o in orders[:n]] == list(range(n))
    assert [BenchConfig.start_order(k, 3) for k in range(99)] == [
        BenchConfig.start_order(k) for k in range(99)
    ]


def test_n_car_config_names_bad_values_and_keeps_the_3_car_manifest():
    with pytest.raises(ValueError, match="races must be a multiple of n_cars = 4 .* got 6"):
        BenchConfig(n_cars=4, races=6)
    with pytest.raises(ValueError, match="n_cars must be an integer in 2..8, got 9"):
        BenchConfig(n_cars=9, races=9)
    assert "n_cars" not in BenchConfig().to_dict()  # the paper's manifests
    assert BenchConfig(n_cars=4, races=8).to_dict()["n_cars"] == 4
    assert BenchConfig(n_cars=4, races=4).agents == ["alpha", "mpc", "mpc", "mpc"]


def test_a_4_car_benchmark_places_every_car_in_its_region_and_summarises(tmp_path):
    cfg = BenchConfig(
        ego="mpc:zeta=0.95", opponents="raceline", races=4, steps=10, seed=3, n_cars=4
    )
    out = bench_race(cfg, 1)  # race 1: ego from R2
    rec, states = out["record"], out["states"]
    assert rec["start_regions"] == ["R2", "R1", "R3", "R4"] and rec["ego_region"] == "R2"
    s0 = states[0, :, 0]
    assert s0[1] > s0[0] > s0[2] > s0[3]
    assert rec["winner"] in ("ego", "O1", "O2", "O3") and sorted(rec["ranks"]) == [1, 2, 3, 4]
    progress = np.array(rec["progress_m"])
    assert rec["margin_m"] == pytest.approx(progress[0] - progress[1:].max(), abs=1e-3)
    assert states.shape == (11, 4, 6) and np.isfinite(states).all()
    s = bench(cfg, tmp_path, pool=Pool(workers=1, progress_bar=False))
    check_summary_invariants(s, 4)
    assert sorted(s["by_region"]) == ["R1", "R2", "R3", "R4"]
    assert set(s["wins"]) == {"ego", "O1", "O2", "O3"}
    assert "| | ego | O1 | O2 | O3 |" in (tmp_path / "summary.md").read_text()
    assert json.loads((tmp_path / "manifest.json").read_text())["config"]["n_cars"] == 4


def test_paper_cases_are_the_papers_table():
    assert list(PAPER_CASES) == ["I", "II", "III", "IV", "V"]
    assert [c.paper_wins[0] for c in PAPER_CASES.values()] == [61, 52, 76, 73, 91]
    assert all(sum(c.paper_wins) == 99 for c in PAPER_CASES.values())


def test_paper_cases_of_the_extended_space_swap_only_the_learned_opponents():
    from agents.potential import SHIPPED

    assert paper_cases("paper") == PAPER_CASES
    ext = paper_cases("extended")
    assert [c.opponents for c in ext.values()] == [
        "alpha:space=extended,model=extended_gamma0.98",
        "alpha:space=extended,model=extended_gamma0.995",
        "alpha:space=extended,model=extended_races400",
        "ibr",
        "ppo",
    ]
    models = [c.opponents.split("model=")[1] for c in ext.values() if "model=" in c.opponents]
    assert models and all(m in SHIPPED for m in models)
    assert [c.paper_wins for c in ext.values()] == [c.paper_wins for c in PAPER_CASES.values()]
    with pytest.raises(ValueError, match="space"):
        paper_cases("wide")


def test_paper_cases_of_the_full_size_class_are_its_models_variants():
    from agents.alpha_agent import CLASS_MODELS

    full = paper_cases("paper", "fullsize")
    base = CLASS_MODELS["fullsize"]
    assert [c.opponents for c in full.values()] == [
        f"alpha:model={base}_gamma0.98",
        f"alpha:model={base}_gamma0.995",
        f"alpha:model={base}_races400",
        "ibr",
        "ppo",
    ]
    assert "(alpha, fullsize, gamma 0.98)" in full["I"].title
    with pytest.raises(ValueError, match="vehicle class 'f1': expected one of orca, fullsize"):
        paper_cases("paper", "f1")


def test_the_paper_tables_wake_is_for_the_full_size_class(tmp_path, capsys):
    argv = ["bench", "--paper-table", "--wake", "0.5", "--out", str(tmp_path)]
    assert main(argv) == 2
    assert "--wake is for --vehicle-class fullsize" in capsys.readouterr().err


def test_bench_space_needs_the_paper_table(capsys):
    assert main(["bench", "--space", "extended"]) == 2
    assert "--paper-table" in capsys.readouterr().err


def test_bench_race_places_cars_in_their_regions_and_names_the_winner():
    out = bench_race(TINY, 2)  # race 2: ego from R3
    rec, states = out["record"], out["states"]
    assert rec["start_regions"] == ["R3", "R1", "R2"] and rec["ego_region"] == "R3"
    s0 = states[0, :, 0]
    assert s0[1] > s0[2] > s0[0]  # O1 (R1) ahead of O2 (R2) ahead of ego
    progress = np.array(rec["progress_m"])
    assert rec["winner"] == ("ego", "O1", "O2")[int(np.argmax(progress))]
    assert rec["margin_m"] == pytest.approx(progress[0] - progress[1:].max(), abs=1e-3)
    assert sorted(rec["ranks"]) == [1, 2, 3]
    assert states.shape == (16, 3, 6) and np.isfinite(states).all()


def test_bad_config_is_refused():
    with pytest.raises(ValueError, match="races must be a positive integer, got 0"):
        BenchConfig(races=0)
    with pytest.raises(ValueError, match="opponents must be an agent spec"):
        BenchConfig(opponents="")


# ---------------------------------------------------------------------------- outputs
def check_summary_invariants(s: dict, races: int) -> None:
    assert s["races"] == races
    assert sum(w["wins"] for w in s["wins"].values()) == races
    for w in list(s["wins"].values()) + [
        w for reg in s["by_region"].values() for k, w in reg.items() if k != "margin_m_mean"
    ]:
        lo, hi = w["ci95"]
        assert 0 <= lo <= w["fraction"] <= hi <= 1
    assert sum(reg["ego"]["races"] for reg in s["by_region"].values()) == races


def test_bench_writes_consistent_outputs_and_resumes_after_a_kill(tmp_path):
    summary = bench(TINY, tmp_path, pool=Pool(workers=1, progress_bar=False))
    check_summary_invariants(summary, 4)
    lines = (tmp_path / "races.jsonl").read_text().splitlines()
    assert sorted(json.loads(line)["race"] for line in lines) == [0, 1, 2, 3]
    assert "| wins (all) |" in (tmp_path / "summary.md").read_text()
    # a kill while writing: the last line torn, one race's states lost
    first = {json.loads(line)["race"]: json.loads(line) for line in lines}
    (tmp_path / "races.jsonl").write_text("\n".join(lines[:3]) + "\n" + lines[3][:20])
    lost = json.loads(lines[3])["race"]
    run = BenchRun(tmp_path, TINY)
    assert run.missing() == [lost]
    again = bench(TINY, tmp_path, pool=Pool(workers=1, progress_bar=False))
    check_summary_invariants(again, 4)
    redone = BenchRun(tmp_path, TINY).records()[lost]
    assert redone["progress_m"] == first[lost]["progress_m"]  # deterministic per race


def test_opening_a_stored_benchmark_to_read_writes_nothing(tmp_path):
    """The analyses read other folders' races (the overtake animation): a folder made
    before manifests recorded provenance must not gain this commit's."""
    from experiments.analysis.nash_figures import find_overtake

    bench(TINY, tmp_path, pool=Pool(workers=1, progress_bar=False))
    manifest = tmp_path / "manifest.json"
    old = json.loads(manifest.read_text())
    old.pop("provenance")
    manifest.write_text(json.dumps(old))
    before = manifest.read_bytes()
    run = BenchRun.open(tmp_path)
    assert run.config == TINY and sorted(run.records()) == [0, 1, 2, 3]
    assert run.states(0).shape == (TINY.steps + 1, 3, 6)
    find_overtake([tmp_path])
    assert manifest.read_bytes() == before


def test_a_folder_of_another_config_is_refused(tmp_path):
    BenchRun(tmp_path, TINY)
    with pytest.raises(ValueError, match="another config"):
        BenchRun(tmp_path, BenchConfig(ego="mpc", opponents="raceline", races=4, steps=15))


def test_summary_by_region_counts_each_ego_start(tmp_path):
    recs = [bench_race(TINY, k)["record"] for k in range(3)]
    s = summarise(recs, TINY)
    assert sorted(s["by_region"]) == ["R1", "R2", "R3"]
    assert all(reg["ego"]["races"] == 1 for reg in s["by_region"].values())


def test_unknown_paper_case_is_refused(tmp_path):
    assert main(["bench", "--paper-table", "--cases", "VI", "--out", str(tmp_path)]) == 2


@pytest.mark.slow
def test_ray_backend_gives_the_same_races_as_the_local_pool(tmp_path):
    pytest.importorskip("ray")
    cfg = BenchConfig(ego="mpc:zeta=0.95", opponents="raceline", races=3, steps=10, seed=5)
    a = bench(cfg, tmp_path / "local", pool=Pool(workers=2, progress_bar=False))
    b = bench(cfg, tmp_path / "ray", pool=Pool(workers=2, backend="ray", progress_bar=False))
    ra, rb = BenchRun(tmp_path / "local", cfg).records(), BenchRun(tmp_path / "ray", cfg).records()
    assert sorted(ra) == sorted(rb) == [0, 1, 2]
    assert all(ra[k]["progress_m"] == rb[k]["progress_m"] for k in ra)
    assert a["wins"] == b["wins"]


# ---------------------------------------------------------------------------- threads
def _native_threads(_):
    """A task reporting its BLAS thread count and the thread variables (module level: pickled)."""
    import os

    from threadpoolctl import threadpool_info

    blas = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
    return blas, os.environ.get("OPENBLAS_NUM_THREADS")


def test_tasks_run_on_one_native_thread_in_workers_and_in_the_driver():
    from threadpoolctl import threadpool_info

    from experiments.infra.parallel import run_tasks

    before = {p["filepath"]: p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"}
    for workers in (1, 2):
        out = {}
        run_tasks(_native_threads, [(k, (k,)) for k in range(2)], out.__setitem__, Pool(workers))
        assert all(blas and set(blas) == {1} for blas, _ in out.values()), out
        if workers == 2:
            assert all(var == "1" for _, var in out.values())
    after = {p["filepath"]: p["num_threads"] for p in threadpool_info()}
    assert {f: after[f] for f in before} == before  # the driver's own, restored


def test_alpha_races_are_the_same_with_1_and_2_workers(tmp_path):
    cfg = BenchConfig(ego="alpha", opponents="mpc", races=2, steps=15, seed=1)
    bench(cfg, tmp_path / "one", pool=Pool(workers=1, progress_bar=False))
    bench(cfg, tmp_path / "two", pool=Pool(workers=2, progress_bar=False))
    one, two = BenchRun(tmp_path / "one", cfg), BenchRun(tmp_path / "two", cfg)
    r1, r2 = one.records(), two.records()
    assert sorted(r1) == sorted(r2) == [0, 1]
    for k in r1:
        assert r1[k]["progress_m"] == r2[k]["progress_m"] and r1[k]["winner"] == r2[k]["winner"]
        assert one.states(k).tobytes() == two.states(k).tobytes()


_BATCHED_SCRIPT = """
import sys
import numpy as np
from racing_env.core import BatchedRaces
races = BatchedRaces("default", n_races=64, seed=0)        # >= 16 races: the parallel kernels
races.reset(seed=0)
rng = np.random.default_rng(1)
states = []
for _ in range(40):
    races.step(rng.uniform(-1, 1, (64, races.config.n_cars, 2)))
    races.observe()
    states.append(races.state.copy())
np.save(sys.argv[1], np.array(states))
"""


@pytest.mark.slow
def test_batched_races_are_identical_with_1_and_2_numba_threads(tmp_path):
    """The simulator's kernels parallel over races give every race the same result whatever
    numba's thread count (each race is one thread's work)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    out = []
    for n in (1, 2):
        env = {
            **os.environ,
            "NUMBA_NUM_THREADS": str(n),
            "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]),
        }
        path = tmp_path / f"states_{n}.npy"
        subprocess.run(
            [sys.executable, "-c", _BATCHED_SCRIPT, str(path)],
            env=env,
            cwd=root,
            check=True,
            timeout=300,
        )
        out.append(np.load(path))
    assert out[0].shape == (40, 64, 3, 6) and np.isfinite(out[0]).all()
    assert out[0].tobytes() == out[1].tobytes()


def test_a_folder_of_another_env_version_is_refused(tmp_path):
    # races of env v1 (manifests without "env") and v2 never mix in one folder
    from experiments.evaluation.bench import SCHEMA_VERSION, BenchRun
    from experiments.infra.artifacts import env_version

    cfg = BenchConfig(ego="raceline", opponents="raceline", races=3, steps=5)
    BenchRun(tmp_path / "new", cfg)
    stored = json.loads((tmp_path / "new" / "manifest.json").read_text())
    assert stored["env"] == env_version() == "alpha_racer_v2"
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "manifest.json").write_text(
        json.dumps({"schema_version": SCHEMA_VERSION, "config": cfg.to_dict()})
    )
    with pytest.raises(ValueError, match="alpha_racer_v1 or older"):
        BenchRun(tmp_path / "old", cfg)


# ---------------------------------------------------------------------------- strategy metrics
def test_ego_regions_fix_the_egos_seat_and_keep_the_default_manifest():
    assert BenchConfig().to_dict() == {
        "ego": "alpha",
        "opponents": "mpc",
        "races": 99,
        "steps": 500,
        "track": "default",
        "seed": 0,
    }
    cfg = BenchConfig(races=5, ego_regions=("R2", "R3"))
    assert [cfg.order(k) for k in range(4)] == [[1, 0, 2], [2, 0, 1]] * 2
    assert cfg.to_dict()["ego_regions"] == ["R2", "R3"]
    assert [BenchConfig().order(k) for k in range(6)] == [
        BenchConfig.start_order(k) for k in range(6)
    ]
    with pytest.raises(ValueError, match=r"ego_regions .* R1, R2, R3, got \['R4'\]"):
        BenchConfig(ego_regions=("R4",))
    with pytest.raises(ValueError, match=r"ego_regions .* got \[\]"):
        BenchConfig(ego_regions=())


def test_records_carry_the_metrics_of_their_stored_states_and_old_folders_get_them(tmp_path):
    from experiments.evaluation.metrics import RECORD_KEYS, record_metrics

    summary = bench(TINY, tmp_path, pool=Pool(workers=1, progress_bar=False))
    run = BenchRun(tmp_path, TINY)
    for k, rec in run.records().items():
        assert {key: rec[key] for key in RECORD_KEYS} == record_metrics(run.states(k))
    st = summary["strategy"]
    assert st["races"] == 4 and st["missing"] == 0
    assert sum(st["wins_by_start_region"].values()) == 4
    wfb = sum(r["won_from_behind"] for r in run.records().values())
    assert sum(st["wins_from_behind"].values()) == wfb
    # an old folder: records without the metrics, states on disk -> the same summary
    lines = (tmp_path / "races.jsonl").read_text().splitlines()
    old = [{k: v for k, v in json.loads(line).items() if k not in RECORD_KEYS} for line in lines]
    (tmp_path / "races.jsonl").write_text("".join(json.dumps(r) + "\n" for r in old))
    again = BenchRun(tmp_path, TINY).write_summary()
    assert again["strategy"] == st
    # records without metrics and without states: missing, said so, never zeros
    s = summarise(old, TINY)
    assert s["strategy"]["races"] == 0 and s["strategy"]["passes"] is None
    from experiments.evaluation.bench_summary import summary_markdown

    md = summary_markdown(s)
    assert "| passes per race (held 1 s, clear sideways) | - | - | - |" in md
    assert "Strategy metrics missing for all 4 races" in md
    half = summarise(
        old[:2]
        + [
            BenchRun(tmp_path, TINY).records_with_metrics()[k]
            for k in (old[2]["race"], old[3]["race"])
        ],
        TINY,
    )
    assert half["strategy"]["races"] == 2 and half["strategy"]["missing"] == 2
    assert "over 2 of 4 races" in summary_markdown(half)


@pytest.mark.parametrize(
    "config",
    [
        BenchConfig(ego="alpha", opponents="ibr", races=3, steps=25, seed=4),
        BenchConfig(ego="mpc:zeta=0.95", opponents="ppo", races=3, steps=25, seed=5),
        BenchConfig(
            ego="mpc:zeta=1.0",
            opponents="raceline",
            races=2,
            steps=40,
            n_cars=2,
            track="tumftm:Monza",
            vehicle_class="fullsize",
        ),
    ],
    ids=["alpha-ibr", "mpc-ppo", "fullsize"],
)
def test_benchmark_races_in_a_batch_are_the_races_run_alone(config):
    """The benchmark's lockstep batch (bench_races, what run_many's pool tasks run) gives each
    race run_race gives alone, bit for bit, with the same record."""
    from experiments.evaluation.bench import bench_races
    from experiments.evaluation.race import run_race

    ks = list(range(config.races))
    batch = bench_races(config, ks)
    for k, got in zip(ks, batch):
        alone, _ = run_race(
            config.agents,
            track=config.track,
            seed=config.race_seed(k),
            max_cycles=config.steps,
            order=config.order(k),
            progress_bar=False,
            vehicle_class=config.vehicle_class,
            wake=config.wake,
        )
        assert np.array_equal(got["states"], alone.states.astype(np.float32))
        rec = got["record"]
        assert rec["progress_m"] == [round(float(v), 4) for v in alone.progress]
        assert rec["contacts"] == alone.contacts.tolist()
        assert rec["off_tracks"] == alone.off_tracks.tolist()
    assert bench_race(config, 1)["record"]["progress_m"] == batch[1]["record"]["progress_m"]
