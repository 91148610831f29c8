"""experiments.infra.artifacts.ResumableRun: the one claim / records / missing / add of bench,
league, policy map and the strategy suite's pace races."""

import json

import pytest

from experiments.infra.artifacts import ResumableRun, as_stored, claim
from experiments.infra.parallel import Pool


class Squares(ResumableRun):
    what = "squares"
    records_name = "rows.jsonl"

    def __init__(self, out, config: dict):
        super().__init__(out, config)
        self.claim({"config": config})

    def tasks(self):
        return [("sq", k) for k in range(self.config["n"])]

    def record_key(self, record):
        return ("sq", record["k"])


def test_a_run_resumes_with_the_missing_tasks(tmp_path):
    run = Squares(tmp_path, {"n": 4, "shape": (2, 3)})
    assert run.missing() == [("sq", k) for k in range(4)]
    run.add({"k": 2, "v": 4})
    run.add({"k": 0, "v": 0})
    with open(run.records_path, "a") as f:  # a kill mid-write: a torn last line
        f.write('{"k": 1, "v"')
    again = Squares(tmp_path, {"n": 4, "shape": (2, 3)})  # tuples equal the stored lists
    assert again.missing() == [("sq", 1), ("sq", 3)]
    again.add({"k": 1, "v": 1})
    assert sorted(again.records()) == [("sq", 0), ("sq", 1), ("sq", 2)]
    assert json.loads(again.manifest_path.read_text()) == {"config": {"n": 4, "shape": [2, 3]}}


def _square(k: int) -> dict:
    return {"k": k, "v": k * k}


def test_run_missing_runs_and_stores_only_the_missing_tasks(tmp_path):
    run = Squares(tmp_path, {"n": 4})
    run.add({"k": 1, "v": 1})
    kw = dict(pool=Pool(workers=1, progress_bar=False), desc="squares", unit="task")
    assert run.run_missing(_square, lambda task: (task[1],), **kw) == 3
    assert {k: rec["v"] for (_, k), rec in run.records().items()} == {0: 0, 1: 1, 2: 4, 3: 9}
    assert run.run_missing(_square, lambda task: (task[1],), **kw) == 0


def test_a_run_of_another_configuration_is_refused(tmp_path):
    Squares(tmp_path, {"n": 4})
    with pytest.raises(
        ValueError,
        match=r"holds squares of another configuration \(config: "
        r"stored \{'n': 4\}, this run \{'n': 5\}\)",
    ):
        Squares(tmp_path, {"n": 5})


def test_claim_compares_configs_as_stored(tmp_path):
    meta = {"config": {"tracks": ("default", "oval"), "seed": 0}}
    claim(tmp_path / "manifest.json", meta, "a test")
    claim(tmp_path / "manifest.json", meta, "a test")  # no refusal of its own tuples
    assert as_stored(meta) == json.loads((tmp_path / "manifest.json").read_text())


def test_a_record_can_be_dropped_or_refused(tmp_path):
    class Checked(Squares):
        def check_record(self, record):
            if record["k"] < 0:
                raise ValueError(f"record {record['k']} is not of this run")
            return record["k"] % 2 == 0

    run = Checked(tmp_path, {"n": 3})
    for k in range(3):
        run.add({"k": k})
    assert run.missing() == [("sq", 1)]
    run.add({"k": -1})
    with pytest.raises(ValueError, match="record -1 is not of this run"):
        run.records()


def test_a_pool_is_checked_when_made():
    assert Pool() == Pool(workers=2, backend="local", address=None, progress_bar=True)
    with pytest.raises(ValueError, match="workers must be a positive integer, got 0"):
        Pool(workers=0)
    with pytest.raises(ValueError, match="backend must be 'local' or 'ray', got 'spark'"):
        Pool(backend="spark")
