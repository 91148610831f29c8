"""The anchored alpha (issue 48, the room): ``alpha:anchor=best`` drives, at every decision,
the candidate among the track's best fixed theta and its one-parameter moves that the
potential ranks highest against the others' maximising thetas; the candidates are the rollout
oracle's, so the two choose from the same set by different criteria."""

from __future__ import annotations

import numpy as np
import pytest

from agents import make_agent_spec
from agents.best_theta import best_theta
from agents.potential import cached_model
from agents.theta import MOVES, Theta, moved_thetas
from racing_env.tracks import make_track

MODEL = "fullsize_monza"  # shipped, extended space, 3 cars


@pytest.fixture(scope="module")
def monza():
    return make_track("tumftm:Monza", vehicle_class="fullsize")


def _joint(rng, track):
    """A 3-car full-size state near the start: (3, 6)."""
    x = np.zeros((3, 6))
    x[:, 0] = 200.0 + rng.uniform(0.0, 60.0, 3)
    x[:, 1] = rng.uniform(-3.0, 3.0, 3)
    x[:, 3] = rng.uniform(40.0, 70.0, 3)
    return x


def test_moved_thetas_are_nested_one_parameter_moves():
    base = Theta(q=5.0, zeta=0.99, s1=0.3, s2=5.0, s3=2.0, b=0.8)
    moved = moved_thetas(base, len(MOVES))
    assert moved[0] == base and moved_thetas(base, 3) == moved[:4]
    for theta, move in zip(moved[1:], MOVES):
        key, _, value = move.partition("=")
        changed = [
            k for k in ("q", "zeta", "s1", "s2", "s3", "b") if getattr(theta, k) != getattr(base, k)
        ]
        assert getattr(theta, key) == float(value) and changed in ([key], [])
    with pytest.raises(ValueError, match="moves must be an integer in 0..8, got 9"):
        moved_thetas(base, 9)


def test_best_candidate_is_the_argmax_of_the_full_potential(monza):
    """The restricted network's ranking is the full network's: Phi of the joint theta with
    car 0's row set to each candidate, from the features built from scratch."""
    model = cached_model(MODEL)
    rng = np.random.default_rng(3)
    sp = model.space
    for _ in range(5):
        x = _joint(rng, monza)
        joint = rng.uniform(sp.low, sp.high, (3, sp.dim))
        cands = rng.uniform(sp.low, sp.high, (6, sp.dim))
        k, phi = model.best_candidate(x, monza, joint, cands)
        full = []
        for c in cands:
            th = joint.copy()
            th[0] = c
            full.append(float(model.potential(x[None], th[None], monza)[0]))
        assert np.allclose(phi, full, rtol=1e-5, atol=1e-5)  # float32 networks
        assert k == int(np.argmax(full))
    with pytest.raises(ValueError, match=r"joint theta \(3, 6\) and candidates \(M, 6\)"):
        model.best_candidate(x, monza, joint[:, :5], cands)


def test_the_anchored_agent_drives_only_its_candidates(monza):
    agent = make_agent_spec(f"alpha:model={MODEL},anchor=best,moves=4,zeta_max=0.95")
    agent.reset(monza, "car_0", 0)
    base = best_theta(monza, space="extended")
    cands = [t.as_array("extended") for t in moved_thetas(base, 4)]
    rng = np.random.default_rng(0)
    x = _joint(rng, monza)
    for _ in range(4):
        obs = np.concatenate([x[0], (x[1:] - x[0]).ravel(), np.zeros(agent.n_preview)])
        u = agent.act(obs.astype(np.float32))
        assert np.all(np.isfinite(u))
        driven = agent.theta.as_array("extended")
        match = [np.array_equal(driven[[0, 2, 3, 4, 5]], c[[0, 2, 3, 4, 5]]) for c in cands]
        assert any(match)
        assert driven[1] == min(cands[match.index(True)][1], 0.95)  # zeta capped as driven
        x[:, 0] += 5.0
    share = agent.stats["candidate_share"]
    assert len(share) == 5 and abs(sum(share) - 1.0) < 1e-3 and len(agent.choices) == 4


def test_with_others_best_the_candidates_face_the_best_theta(monza):
    """``others="best"``: the candidate driven is the potential's best reply to the others
    racing the anchor's theta (not the maximiser's thetas)."""
    from agents.alpha_agent import split_observation

    agent = make_agent_spec(f"alpha:model={MODEL},anchor=best,others=best")
    agent.reset(monza, "car_0", 0)
    model = cached_model(MODEL)
    cands = np.array(
        [t.as_array("extended") for t in moved_thetas(best_theta(monza, space="extended"), 4)]
    )
    cands[:, 1] = np.minimum(cands[:, 1], model.zeta_ceiling or np.inf)
    x = _joint(np.random.default_rng(1), monza)
    obs = np.concatenate([x[0], (x[1:] - x[0]).ravel(), np.zeros(agent.n_preview)])
    agent.act(obs.astype(np.float32))
    ego, others = split_observation(obs.astype(np.float32), agent.n_preview)
    joint = np.vstack([ego[None], others])
    k, _ = model.best_candidate(joint, monza, np.tile(cands[0], (3, 1)), cands)
    assert agent.choices == [k]
    assert np.array_equal(agent.theta.as_array("extended"), cands[k])


def test_with_others_best_alone_only_the_ego_s_theta_is_maximised(monza):
    """Without an anchor, ``others="best"`` maximises over the ego's theta alone: the others'
    rows are the best fixed theta exactly, and the ego's Phi is at least that of a dense
    search's best of 200 random thetas of its own (the ascent does not leave the others' rows
    to find more)."""
    model = cached_model(MODEL)
    agent = make_agent_spec(f"alpha:model={MODEL},others=best")
    agent.reset(monza, "car_0", 0)
    best = best_theta(monza, space="extended").as_array("extended")
    x = _joint(np.random.default_rng(2), monza)
    obs = np.concatenate([x[0], (x[1:] - x[0]).ravel(), np.zeros(agent.n_preview)])
    agent.act(obs.astype(np.float32))
    joint = agent._theta_joint
    assert np.array_equal(joint[1:], np.tile(best, (2, 1)))
    ego_state = obs[:6].astype(float)
    state = np.vstack([ego_state, (obs[6:18].reshape(2, 6) + ego_state)])
    state[1:, 2] = np.angle(np.exp(1j * state[1:, 2]))
    rng = np.random.default_rng(0)
    sp = model.space
    draws = rng.uniform(sp.low, sp.high, (200, sp.dim))
    draws[:, 1] = np.minimum(draws[:, 1], model.zeta_ceiling or sp.high[1])
    _, phis = model.best_candidate(state, monza, joint, draws)
    assert agent.last_potential >= phis.max() - 1e-6


def test_low_bounds_pin_rows_and_are_checked(monza):
    model = cached_model(MODEL)
    sp = model.space
    x = _joint(np.random.default_rng(4), monza)
    fixed = np.tile(sp.low + 0.3 * (sp.high - sp.low), (3, 1))
    low, high = np.tile(sp.low, (3, 1)), np.tile(sp.high, (3, 1))
    low[1:] = high[1:] = fixed[1:]
    theta, _ = model.maximise(x, monza, None, high=high, low=low)
    assert np.allclose(theta[1:], fixed[1:], rtol=0, atol=1e-9)
    assert np.all(theta[0] >= sp.low) and np.all(theta[0] <= sp.high)
    with pytest.raises(ValueError, match=r"low must be \(N, 6\) = \(3, 6\) lower bounds"):
        model.maximise(x, monza, None, low=np.zeros((3, 6)))


@pytest.mark.filterwarnings("ignore:track 'Spa'")  # its width narrowed at two points
@pytest.mark.parametrize("extra", ["anchor=best", "others=best"])
def test_a_track_without_a_best_theta_is_refused_before_the_races(extra):
    """Both options read the best-theta table: a circuit without an entry fails at the
    run's track check, naming the command that adds it."""
    agent = make_agent_spec(f"alpha:model={MODEL},{extra}")
    spa = make_track("tumftm:Spa", vehicle_class="fullsize")
    with pytest.raises(
        ValueError, match="no best fixed theta of the 'extended' policy space for track 'Spa'"
    ):
        agent.check_track(spa)


@pytest.mark.parametrize(
    "spec, message",
    [
        ("alpha:model=fullsize_monza,anchor=best,others=known", "others must be one of"),
        ("alpha:model=fullsize_monza,anchor=worst", "anchor must be 'best' or left out"),
        ("alpha:model=fullsize_monza,anchor=best,moves=12", "moves must be an integer in 0..8"),
        (
            "alpha:model=fullsize_monza,anchor=best,anchor_space=wake",
            "anchor_space='wake' has more parameters than the agent's space 'extended'",
        ),
    ],
)
def test_bad_anchors_are_named(spec, message):
    with pytest.raises(ValueError, match=message):
        make_agent_spec(spec)
