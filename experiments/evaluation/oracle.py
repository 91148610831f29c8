"""The room a choice of theta has: a rollout oracle (issue 48, "the room").

Every ``every`` control periods the oracle ego copies the race as it stands (the env and
every agent, :func:`copy.deepcopy`; a copied race goes on bit for bit,
``tests/test_agent_copies.py``), drives each of its candidate thetas in its own copy for
``lookahead`` seconds while the other cars drive their own policies (their agents' copies),
and keeps, until the next choice, the candidate with the best relative progress at the end:
its progress minus the best other car's. It sees the exact joint state and the other cars'
policies, so it is an upper reference for what a state-dependent choice of theta can gain over
a fixed one, not a racing agent: its margin over the fixed theta in the same seats is the
room.

With ``model`` the oracle keeps the exact state but not the other cars' policies: its
rollouts drive them by a model (an agent spec per car, for example its own base theta),
whose copies shadow the race, acting on the real observations at every period (their
actions unused) so that they are warm where the real cars' agents are. The state is what
every car's observation holds in full (each car's ``s, n, mu, vx, vy, omega``; the wake and
the contact rule follow from it), so an oracle with a model uses only what a racing agent
sees and what it assumes of the others: it measures how much of the room a look-ahead of
one's own can take. With the others' own specs as the model it is the oracle, bit for bit.

Cost: ``M`` candidates times ``lookahead / dt`` periods of every car at every choice, on top of
the race: with 6 candidates, a 3 s look-ahead and a choice every second, 18 times the race.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agents import make_agent_spec
from agents.base import parse_value, spec_params, spec_with
from agents.mpc_agent import MPCAgent, copy_sharing_lines
from agents.theta import move_items
from experiments.evaluation.race import agent_seed, start_race
from racing_env import RacingParallelEnv
from racing_env.parallel_env import relative_progress


def candidate_moves(spec: str, moves: int = 4) -> list[str]:
    """``spec`` (an ``mpc`` agent spec) and ``spec`` with one parameter moved, for the first
    ``moves`` of :data:`agents.theta.MOVES` (nested: the candidates of ``moves = m`` are the first
    ``m + 1`` of ``moves = m + 1``); a move that leaves the car as it was (``s1=0`` of a base
    whose ``s1`` is 0, or ``zeta=0.95`` of a base capped at ``zeta_max=0.88``) is left out, so
    no candidate is simulated twice. A ValueError for
    ``moves`` outside 0..len(MOVES)."""
    out = [spec]
    seen = [_parsed(spec)]
    for k, v in move_items(moves):
        moved = spec_with(spec, **{k: v})
        if _parsed(moved) not in seen:
            out.append(moved)
            seen.append(_parsed(moved))
    return out


def _parsed(spec: str) -> tuple[str, dict]:
    """An agent spec's name and parsed values, the same for specs that differ only in order,
    in how a number is written (``0`` and ``0.0``) or in a zeta above the spec's ``zeta_max``
    (the MPC drives with ``min(zeta, zeta_max)``, so those are one car)."""
    name, params = spec_params(spec)
    values = {k: parse_value(v) for k, v in params.items()}
    cap, zeta = values.get("zeta_max"), values.get("zeta")
    if isinstance(cap, (int, float)) and isinstance(zeta, (int, float)):
        values["zeta"] = min(zeta, cap)
    return name, values


@dataclass(frozen=True)
class OracleResult:
    """One oracle race: ``progress`` (N,) [m] of every car from its start (the oracle is car
    0), ``winner`` (the car with the most progress), ``choices`` the candidate index kept at
    each choice, ``scores`` (choices, M) every candidate's relative progress [m] at the end of
    its look-ahead (cut short where the race ends first), ``observations`` (choices, D)
    float32: the oracle's env observation at each choice (what a policy choosing from the
    state would see; :mod:`agents.ranked` learns the choice from them)."""

    progress: np.ndarray
    winner: int
    choices: list[int]
    scores: np.ndarray
    observations: np.ndarray


def _candidate_thetas(candidates: list[str]) -> tuple[MPCAgent, list]:
    """The oracle's agent (the first candidate's) and every candidate's theta; a ValueError
    unless every candidate is an ``mpc`` agent of the same policy space."""
    if not candidates:
        raise ValueError("an oracle needs at least one candidate (an mpc agent spec)")
    agents = [make_agent_spec(spec) for spec in candidates]
    for spec, agent in zip(candidates, agents):
        if type(agent) is not MPCAgent:
            raise ValueError(
                f"oracle candidate {spec!r} is not an mpc agent spec (mpc:q=..,zeta=..)"
            )
        if agent.space != agents[0].space:
            raise ValueError(
                f"oracle candidates must share one policy space: {candidates[0]!r} is "
                f"{agents[0].space!r}, {spec!r} is {agent.space!r}"
            )
    return agents[0], [a.theta for a in agents]


def oracle_race(
    candidates: list[str],
    opponents: list[str],
    track: str = "default",
    seed: int = 0,
    order: list[int] | None = None,
    steps: int = 500,
    lookahead: float = 3.0,
    every: int = 10,
    vehicle_class: str | None = None,
    wake: float | None = None,
    model: list[str] | None = None,
) -> OracleResult:
    """Race the oracle (car 0, choosing among the thetas of the ``candidates``, ``mpc`` agent
    specs of one policy space) against ``opponents`` (agent specs) on ``track`` for ``steps``
    control periods, choosing every ``every`` periods with a look-ahead of ``lookahead``
    seconds (module docstring). ``seed`` and ``order`` (each car's start region, 0 = R1) as
    for :func:`experiments.evaluation.race.run_race`, and started as it starts its races
    (:func:`~experiments.evaluation.race.start_race`), so that with one candidate the race is
    ``run_race`` of that candidate, bit for bit. ``model`` (one agent spec per opponent, or
    None for their own agents' copies): how the rollouts drive the other cars (module
    docstring)."""
    if not (isinstance(every, int) and every >= 1):
        raise ValueError(f"every must be a positive number of periods, got {every!r}")
    if not (np.isfinite(lookahead) and lookahead > 0):
        raise ValueError(f"lookahead must be a positive time [s], got {lookahead!r}")
    oracle, thetas = _candidate_thetas(list(candidates))
    env = RacingParallelEnv(
        track=track,
        n_cars=1 + len(opponents),
        max_cycles=steps,
        vehicle_class=vehicle_class,
        wake=wake,
    )
    agents = [oracle, *(make_agent_spec(spec) for spec in opponents)]
    if model is not None and len(model) != len(opponents):
        raise ValueError(
            f"model must name one agent spec per opponent ({len(opponents)}), got {model!r}"
        )
    shadows = None if model is None else [make_agent_spec(spec) for spec in model]
    obs = start_race(env, agents, seed, order)
    planners = agents if shadows is None else [oracle, *shadows]
    for k, (shadow, aid) in enumerate(zip(shadows or [], env.possible_agents[1:]), start=1):
        shadow.reset(env.track, aid, agent_seed(seed, k))
    n_ahead = max(1, int(round(lookahead / env.config.dt)))
    choices: list[int] = []
    scores: list[np.ndarray] = []
    seen: list[np.ndarray] = []
    step = 0
    while env.agents:
        if step % every == 0 and len(thetas) > 1:
            row = np.array([_rollout(env, planners, obs, theta, n_ahead) for theta in thetas])
            best = int(np.argmax(row))  # the first of equals
            choices.append(best)
            scores.append(row)
            seen.append(np.array(obs[env.possible_agents[0]], dtype=np.float32))
            oracle.theta = thetas[best]
        for shadow, aid in zip(shadows or [], env.possible_agents[1:]):
            shadow.act(obs[aid])  # kept warm on the real race; its action is not driven
        obs = _step(env, agents, obs)
        step += 1
    progress = env.core.state[0, :, 0] - env.core.s_line[0]
    return OracleResult(
        progress=progress.copy(),
        winner=int(np.argmax(progress)),
        choices=choices,
        scores=np.array(scores).reshape(len(scores), len(thetas)),
        observations=np.array(seen, dtype=np.float32).reshape(
            len(seen), env.observation_space(env.possible_agents[0]).shape[0]
        ),
    )


def _step(env: RacingParallelEnv, agents: list, obs: dict) -> dict:
    """One control period: every agent acts on its observation; the next observations."""
    actions = {aid: agents[k].act(obs[aid]) for k, aid in enumerate(env.possible_agents)}
    return env.step(actions)[0]


def _rollout(env, agents, obs, theta, n_steps: int) -> float:
    """The oracle's relative progress after ``n_steps`` periods of a copy of the race, driven
    by copies of ``agents`` (the oracle first), with its theta set to ``theta`` (fewer where
    the race ends first)."""
    env2, agents2, obs2 = copy_sharing_lines((env, agents, obs), agents)
    agents2[0].theta = theta
    for _ in range(n_steps):
        if not env2.agents:
            break
        obs2 = _step(env2, agents2, obs2)
    return relative_progress(env2)
