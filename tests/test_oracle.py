"""The rollout oracle (the room of issue 48): with one candidate it is the fixed-theta race,
bit for bit; with a slow and a fast candidate it keeps the fast one and gains on the slow
one raced fixed; driven by a model of the others it uses that model, and with their own specs
as the model it is the oracle bit for bit; bad candidates are named."""

import numpy as np
import pytest

from experiments.evaluation.oracle import oracle_race
from experiments.evaluation.race import run_race

FAST = "mpc:q=20,zeta=1.0,s1=0.1,s2=4,s3=1"
SLOW = "mpc:q=20,zeta=0.8,s1=0.1,s2=4,s3=1"


def test_one_candidate_is_the_fixed_race():
    oracle = oracle_race([FAST], ["raceline"], seed=5, order=[1, 0], steps=60)
    fixed, _ = run_race([FAST, "raceline"], seed=5, order=[1, 0], max_cycles=60, progress_bar=False)
    assert np.array_equal(oracle.progress, fixed.progress)


def test_the_oracle_keeps_the_faster_theta_and_gains_by_it():
    oracle = oracle_race([SLOW, FAST], ["raceline"], seed=5, order=[1, 0], steps=80, every=20)
    slow, _ = run_race([SLOW, "raceline"], seed=5, order=[1, 0], max_cycles=80, progress_bar=False)
    assert len(oracle.choices) == 4 and oracle.scores.shape == (4, 2)
    assert oracle.choices == [int(np.argmax(row)) for row in oracle.scores]
    assert sum(oracle.choices) >= 3  # the fast candidate, nearly always
    assert oracle.progress[0] > slow.progress[0]


def test_a_model_of_the_others_is_what_the_rollouts_drive():
    """The shadows act on the race's own observations, so with the others' own (stateful MPC)
    specs as the model every score is the full-information oracle's; a wrong model (a
    racing-line follower for an MPC car) changes the scores, not the race's rules."""
    kw = dict(seed=5, order=[1, 0], steps=60, every=20, lookahead=1.0)
    oracle = oracle_race([SLOW, FAST], [FAST], **kw)
    own = oracle_race([SLOW, FAST], [FAST], model=[FAST], **kw)
    assert np.array_equal(own.scores, oracle.scores) and own.choices == oracle.choices
    assert np.array_equal(own.progress, oracle.progress)
    wrong = oracle_race([SLOW, FAST], [FAST], model=["raceline"], **kw)
    assert not np.array_equal(wrong.scores, oracle.scores)
    assert wrong.choices == [int(np.argmax(row)) for row in wrong.scores]


def test_bad_candidates_are_named():
    with pytest.raises(ValueError, match="at least one candidate"):
        oracle_race([], ["raceline"], steps=5)
    with pytest.raises(ValueError, match="'raceline' is not an mpc agent spec"):
        oracle_race(["raceline"], ["raceline"], steps=5)
    with pytest.raises(ValueError, match="share one policy space"):
        oracle_race([FAST, "mpc:space=extended,b=1"], ["raceline"], steps=5)
    with pytest.raises(ValueError, match="every must be a positive"):
        oracle_race([FAST], ["raceline"], steps=5, every=0)
    with pytest.raises(ValueError, match=r"one agent spec per opponent \(1\), got \[\]"):
        oracle_race([FAST], ["raceline"], steps=5, model=[])
