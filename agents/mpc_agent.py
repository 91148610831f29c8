"""The fixed-parameter MPC agent: the paper's policy pi(x; theta) for one fixed theta."""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from racing_env.class_config import CLASS_DEFAULTS
from racing_env.observation import joint_state_from_observation, split_observation  # noqa: F401
from racing_env.track import Track
from racing_env.tracks import make_track
from racing_env.vehicle import VehicleParams
from racing_env.vehicles import FullSizeParams, vehicle_for_track

from .base import median_p99, register_agent
from .best_theta import best_theta
from .mpc import MPC, PLANS, MPCConfig, compiled_solve
from .opponent_prediction import PREDICTIONS, LinePrediction
from .reference import (
    THETA_HIGH,
    THETA_LOW,
    WAKE_HIGH,
    WAKE_LOW,
    WAKE_NAMES,
    WAKE_ONLY,
    Theta,
    in_a_wake,
    policy_space,
    reference_trajectory,
)
from .threads import single_blas_thread

#: Dirty air (worlds with a wake): with a car at most this many car lengths ahead and car widths
#: to the side, the MPC's reference is the race line's speed profile at this share of the
#: car's grip. Behind another car the follower has lost downforce (the wake's downforce
#: factor is 0.5 at one length, 0.79 at seven), so it brakes earlier and corners slower than
#: in clean air; tracking the clean-air profile it arrived 3-6 m/s too fast at Monza's first
#: chicane after a tow and left the track.
DIRTY_AIR = (10.0, 1.5, 0.95)

if TYPE_CHECKING:
    from racing_env.raceline import Raceline


def progress_rate(state: np.ndarray, track: Track) -> np.ndarray:
    """Frenet progress rate ``s_dot`` [m/s] of states (..., 6)."""
    from .mpc import _grid_interp

    state = np.asarray(state, dtype=float)
    s, n, mu, vx, vy = (state[..., i] for i in range(5))
    kappa = _grid_interp(track.kappa, np.ascontiguousarray(s), track.ds, track.length)
    return (vx * np.cos(mu) - vy * np.sin(mu)) / (1.0 - n * kappa)


DEFAULT_THETA = Theta(q=20.0, zeta=0.9, s1=0.1, s2=4.0, s3=1.0)
"""The ``mpc`` agent's theta when none is given: mid-range and safe, 10% below the line's speed."""
BEST = "best"
"""``theta=BEST``: race the track's best fixed theta (:mod:`agents.best_theta`)."""


_T = TypeVar("_T")


def copy_sharing_lines(obj: _T, agents: Sequence) -> _T:
    """``copy.deepcopy(obj)`` that shares, rather than copies, the tracks, racing lines and
    line predictions of the MPC agents among ``agents``: they are never changed in a race, and
    the reference's tables are cached per line object (:mod:`agents.reference_tables`), so a
    copy with its own lines would build them again. A copied race goes on as the original."""
    memo: dict = {}
    for agent in agents:
        if isinstance(agent, MPCAgent):
            for name in ("track", "raceline", "blend_line", "prediction"):
                part = getattr(agent, name, None)  # None before the agent's first reset
                if part is not None:
                    memo[id(part)] = part
    return copy.deepcopy(obj, memo)


@register_agent("mpc")
class MPCAgent:
    """MPC tracking the theta-parametrised reference (paper section 2.2) with fixed theta.

    ``theta`` keywords ``q, zeta, s1, s2, s3`` (each defaults to :data:`DEFAULT_THETA`'s: a
    mid-range, safe setting, zeta 0.9), or ``theta="best"``: at every ``reset(track)`` the
    track's best fixed theta of the agent's policy space (``space``) from the table of
    :mod:`agents.best_theta` (chosen by ``alpha-racer control``, over the extended box with
    ``--space extended``; a track missing from the table, or chosen on another env version,
    is a ``ValueError`` naming the track and the command that adds it; with ``theta="best"``
    the theta keywords must not be given). Further: an
    :class:`MPCConfig`, :class:`VehicleParams`, and the env's ``n_preview`` (to read the
    observation layout), and ``line``, the racing line whose path and speed profile the
    reference shapes (``"curvature"``, the paper's minimum-curvature line, default; or
    ``"lap_time"``, see :class:`racing_env.raceline.RacelineConfig`). ``stats`` reports solves, fallbacks,
    restarts from the follower rollout, and solve times. A decision runs numpy's BLAS on one
    thread (:func:`agents.threads.single_blas_thread`), so its results cannot depend on the
    process's thread count (OpenBLAS measured different last bits with two threads for a
    100 x 100 float64 product with a transposed operand, the MPC's sizes). ``plan``
    (:data:`agents.mpc.PLANS`): ``"rti"`` (default) solves with ``config`` as given,
    ``"damped"`` with damped SQP steps and 20 SQP iterations, whose plans are closer to
    IPOPT's in traffic.

    ``zeta_max`` (default ``None``: no ceiling), a speed-scale ceiling in the theta box's
    zeta range [0.8, 1.05]: the MPC drives with ``min(zeta, zeta_max)`` whatever its theta
    says (``alpha-racer strategy``'s defend scenario handicaps the ego with it; the alpha
    agent maximises its potential within the lowered box instead).

    Vehicle class: at ``reset`` the agent races the track's class (``track.vehicle_class``,
    ``"orca"`` when absent): ``vehicle`` if given (of another class: ``ValueError``), else
    the class's default car; the prediction model, the input bounds, the racing line (with
    the class's scaled settings) and, through :func:`agents.mpc.config.class_scale`, the
    config's lengths, the cost's scale and theta's lengths follow the class.
    """

    #: theta's bounds (:data:`agents.reference.THETA_LOW` / ``THETA_HIGH``), for ``alpha-racer agents``
    param_bounds = {k: (float(lo), float(hi)) for k, lo, hi in zip(WAKE_NAMES, WAKE_LOW, WAKE_HIGH)}
    #: what ``alpha-racer agents`` shows for the theta keywords (their signature default is None)
    param_defaults = {k: getattr(DEFAULT_THETA, k) for k in WAKE_NAMES}
    param_notes = {
        "theta": "'best': the track's best fixed theta of the agent's space, chosen by "
        "alpha-racer control",
        "predict": "where the separation rows expect the other cars: 'constant' progress rate "
        "and offset (the paper's) or along the racing 'line'",
        "plan": "'rti' (the RTI-SQP as configured) or 'damped' (damped SQP steps, 20 "
        "iterations: closer to IPOPT in traffic, 1.4x the solve time)",
    }

    def __init__(
        self,
        q: float | None = None,
        zeta: float | None = None,
        s1: float | None = None,
        s2: float | None = None,
        s3: float | None = None,
        b: float | None = None,
        h: float | None = None,
        p: float | None = None,
        c: float | None = None,
        theta: str | None = None,
        space: str = "paper",
        config: MPCConfig | None = None,
        vehicle: VehicleParams | FullSizeParams | None = None,
        n_preview: int = 10,
        line: str = "curvature",
        zeta_max: float | None = None,
        predict: str = "constant",
        plan: str = "rti",
    ):
        from racing_env.raceline import RacelineConfig

        given = {
            k: v for k, v in zip(WAKE_NAMES, (q, zeta, s1, s2, s3, b, h, p, c)) if v is not None
        }
        if theta is not None and theta != BEST:
            raise ValueError(
                f"theta must be {BEST!r} (the track's best fixed theta) or left out, got {theta!r}"
            )
        if theta == BEST and given:
            raise ValueError(
                f"theta='best' takes the whole theta from the best-theta table; "
                f"drop {', '.join(f'{k}={v!r}' for k, v in given.items())}"
            )
        self.best = theta == BEST
        self.theta = Theta(**{**{k: getattr(DEFAULT_THETA, k) for k in WAKE_NAMES}, **given})
        lo, hi = THETA_LOW[1], THETA_HIGH[1]
        if zeta_max is not None and (
            isinstance(zeta_max, bool)
            or not isinstance(zeta_max, (int, float))
            or not lo <= zeta_max <= hi
        ):
            raise ValueError(
                f"zeta_max must be a number in the theta box's zeta range "
                f"[{lo:g}, {hi:g}], got {zeta_max!r}"
            )
        self.zeta_max = None if zeta_max is None else float(zeta_max)
        self.space = policy_space(space).name
        if self.space == "paper" and self.theta.b != 0:
            raise ValueError(
                f"b = {self.theta.b!r} is a parameter of the extended policy "
                f"space; add space='extended'"
            )
        wake = {k: getattr(self.theta, k) for k in WAKE_ONLY if getattr(self.theta, k)}
        if self.space != "wake" and wake:
            raise ValueError(
                f"{', '.join(f'{k} = {v!r}' for k, v in wake.items())}: parameters of the wake "
                f"policy space; add space='wake'"
            )
        self.raceline_config = RacelineConfig(objective=line)  # names line and choices if bad
        if line != "curvature" and self.theta.b > 0:
            raise ValueError(
                f"b = {self.theta.b!r} blends the lap-time line into the "
                f"minimum-curvature line; it needs line='curvature', got {line!r}"
            )
        if predict not in PREDICTIONS:
            raise ValueError(f"predict must be one of {PREDICTIONS}, got {predict!r}")
        self.predict = predict
        self.n_preview = n_preview  # the env's RaceConfig.n_preview (observation layout)
        if plan not in PLANS:
            raise ValueError(f"plan must be one of {tuple(PLANS)}, got {plan!r}")
        self.plan = plan
        self.config = replace(config or MPCConfig(), **PLANS[plan])
        self.vehicle_given = vehicle
        self.vehicle: VehicleParams | FullSizeParams = vehicle or VehicleParams()
        self.mpc: MPC | None = None
        self.tow = False  # set at reset: the track's class races with a wake
        self.track: Track | None = None

    def reset(self, track: Track | str, agent_id: str = "car_0", seed: int | None = None) -> None:
        from racing_env.controllers import raceline_config_for
        from racing_env.raceline import get_raceline

        track = make_track(track)
        self.vehicle = vehicle_for_track(track, self.vehicle_given, f"{type(self).__name__}")
        if self.best:  # before anything is built: a missing entry fails fast
            self.theta = best_theta(track, space=self.space)
        if self.mpc is None or self.track is not track:
            self.mpc = MPC(track, self.vehicle, self.config, line=self.line)
        self.track = track
        self.raceline = get_raceline(
            track, self.vehicle, raceline_config_for(self.vehicle, self.line)
        )
        self.blend_line: Raceline | None = None  # the lap-time line, built at the first b > 0
        self.prediction = (  # the other cars along the track's minimum-curvature line
            LinePrediction(
                track, get_raceline(track, self.vehicle, raceline_config_for(self.vehicle))
            )
            if self.predict == "line"
            else None
        )
        self.mpc.reset()
        # a world with a wake by default (full size): the reference follows a car in a tow
        self.tow = float(CLASS_DEFAULTS[track.vehicle_class]["wake"]) > 0.0
        self.agent_id = agent_id
        self._u_prev = np.zeros(2)

    def check_track(self, track: Track) -> None:
        """Raise the ``ValueError`` that ``reset(track)`` would for a track without a best
        theta (``theta="best"`` only; nothing is built), so a run fails before its races."""
        if self.best:
            best_theta(track, space=self.space)

    def _pass_side(self) -> str | None:
        """The overtake shift's side rule for :func:`reference_trajectory`: ``"room"`` in the
        extended space and the wake space, which keeps it (the side the car is on, unless the
        car ahead leaves too little room there; chosen again at every step: a side held while
        the same car stays ahead kept the car on the side where the track closes, docs "The
        extended policy space"), ``None`` (the paper's rule) in the paper's space."""
        return "room" if self.space in ("extended", "wake") else None

    def _blend_line(self, theta: Theta) -> Raceline | None:
        """The lap-time race line that ``theta.b`` blends in (None while ``b`` is 0)."""
        if theta.b == 0.0:
            return None
        if self.blend_line is None:
            from racing_env.controllers import raceline_config_for
            from racing_env.raceline import get_raceline

            assert self.track is not None  # reset() sets it
            self.blend_line = get_raceline(
                self.track, self.vehicle, raceline_config_for(self.vehicle, "lap_time")
            )
        return self.blend_line

    @property
    def driven_theta(self) -> Theta:
        """The theta the MPC drives with: ``theta`` with its zeta capped at ``zeta_max``."""
        return self.capped(self.theta)

    def capped(self, theta: Theta) -> Theta:
        """``theta`` as this MPC would drive it: its zeta capped at ``zeta_max``."""
        if self.zeta_max is None or theta.zeta <= self.zeta_max:
            return theta
        return replace(theta, zeta=self.zeta_max)

    @property
    def line(self) -> str:
        """The racing line this agent's reference follows (``RacelineConfig.objective``)."""
        return self.raceline_config.objective

    @property
    def stats(self) -> dict:
        st = self.mpc.stats if self.mpc is not None else {}
        med, p99 = median_p99(st.get("solve_ms", []))
        return {
            "solves": st.get("solves", 0),
            "fallbacks": st.get("fallbacks", 0),
            "restarts": st.get("restarts", 0),
            "solve_ms_median": med,
            "solve_ms_p99": p99,
        }

    def _before_solve(self, observation: np.ndarray) -> None:
        """What an agent does before its MPC step (a subclass's hook: the alpha agent chooses
        its theta here); nothing for the fixed-theta agent."""

    def _solve_args(self, observation: np.ndarray) -> tuple:
        """The arguments of :meth:`MPC.solve <agents.mpc.solver.MPC.solve>` for this
        observation: ``(x0, s_ref, n_ref, q, opponents, u_prev)`` (the references of
        :attr:`driven_theta`, the cars just ahead and behind as the prediction sees them)."""
        track = self.track
        assert track is not None  # reset() sets it with the MPC
        ego, others = split_observation(observation, self.n_preview)
        theta = self.driven_theta
        dirty = self.tow and len(others) and in_a_wake(ego, others, self.vehicle, DIRTY_AIR[:2])
        ref = reference_trajectory(
            theta,
            ego,
            others if len(others) else None,
            self.raceline,
            track,
            K=self.config.horizon,
            dt=self.config.dt,
            blend=self._blend_line(theta),
            side=self._pass_side(),
            vehicle=None if isinstance(self.vehicle, VehicleParams) else self.vehicle,
            tow=self.tow,
            friction=DIRTY_AIR[2] if dirty else None,
        )
        neighbours = [j for j in (ref.ahead, ref.behind) if j >= 0]
        opp = None
        if neighbours:
            o = others[neighbours]
            opp = np.column_stack([o[:, 0], o[:, 1], progress_rate(o, track)])
            if self.prediction is not None:
                s, n, s_dot = opp.T
                opp = self.prediction.paths(s, n, s_dot, self.config.horizon, self.config.dt)
        return ego, ref.s_ref, ref.n_ref, theta.q, opp, self._u_prev

    def _check_reset(self) -> None:
        if self.mpc is None:
            raise RuntimeError(f"{type(self).__name__}.act() before reset(track, ...)")

    def act(self, observation: np.ndarray) -> np.ndarray:
        self._check_reset()
        assert self.mpc is not None
        with single_blas_thread():  # results independent of the BLAS thread count
            self._before_solve(observation)
            u = self.mpc.solve(*self._solve_args(observation))
        self._u_prev = u
        return u.astype(np.float32)

    @classmethod
    def act_group(cls, agents: Sequence[MPCAgent], observations: np.ndarray) -> np.ndarray:
        """Actions (M, 2) float32 of M agents of this kind, ``observations`` (M, D) one row
        each: every row what ``agents[row].act(observations[row])`` gives, with the MPC steps
        of all of them solved together (:func:`agents.mpc.compiled_solve.solve_many`: one
        compiled call per kind of MPC, split over threads). The lockstep runner's batched
        decision (:func:`experiments.infra.lockstep.decide`)."""
        for agent in agents:
            agent._check_reset()
        with single_blas_thread():
            problems = []
            for agent, obs in zip(agents, observations):
                agent._before_solve(obs)
                problems.append(agent._solve_args(obs))
            mpcs = [agent.mpc for agent in agents]
            inputs = compiled_solve.solve_many(mpcs, problems)  # type: ignore[arg-type]
        out = np.empty((len(agents), 2), dtype=np.float32)
        for row, (agent, u) in enumerate(zip(agents, inputs)):
            agent._u_prev = u
            out[row] = u.astype(np.float32)
        return out
