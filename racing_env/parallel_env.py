"""PettingZoo ParallelEnv of N cars racing on a track (the paper's game, section 2)."""
from __future__ import annotations

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from .config import RaceConfig, RulesConfig, StartConfig
from .core import BatchedRaces
from .track import Track
from .vehicle import VehicleParams




class RacingParallelEnv(ParallelEnv):
    """N cars race on a closed track; each wants to gain progress on the leading opponent.

    The cars follow the paper's dynamic bicycle model with Pacejka tyres in the Frenet frame
    (:mod:`racing_env.vehicle`), integrated with adaptive RK4 sub-steps inside each 0.1 s
    control period, under the paper's contact and off-track rules (:class:`RulesConfig`).

    **Agents**: ``car_0 .. car_{N-1}`` for N = 1..8 (N = 1 is a time trial).

    **Action space** (per agent): ``Box(-1, 1, (2,), float32)``: ``[throttle, steering]``.
    Throttle -1 is full brake and +1 full throttle (mapped affinely onto the vehicle's
    ``[d_min, d_max]``); steering maps onto ``[-delta_max, delta_max]`` rad, positive left.
    Values outside the box (``+-inf`` included) are clipped to it; a NaN, an action of another
    shape, or an action for an agent that is not live raises ``ValueError`` naming the agent.

    **Observation space** (per agent, ``Box`` float32 of size ``6 N + n_preview``):

    ==========================  =============================================================
    entries                     meaning
    ==========================  =============================================================
    0..5                        own ``s mod L`` [m], ``n`` [m], ``mu`` [rad], ``vx``, ``vy``
                                [m/s], ``omega`` [rad/s]
    6 + 6k .. 11 + 6k           the k-th other car (others in index order) relative to this
                                one: ``s_j - s_i`` on unwrapped progress (a car a lap ahead
                                is ``+L`` ahead), ``n_j - n_i``, ``mu_j - mu_i`` (wrapped),
                                ``vx_j - vx_i``, ``vy_j - vy_i``, ``omega_j - omega_i``
    last ``n_preview``          track curvature [1/m] at ``s_i + k * preview_ds``, k = 0..
    ==========================  =============================================================

    ``state()`` returns the global joint state: every car's ``(s, n, mu, vx, vy, omega)`` with
    unwrapped ``s``, flattened in agent order (``6 N`` float32).

    **Reward**: per step, the change of ``s_i - max_{j != i} s_j`` [m] on unwrapped arc
    length (the paper's relative progress; ``s_i`` alone when N = 1). Crossing the start/finish
    line causes no jump and driving backwards always costs reward.

    **Starting state** (``start``, see :class:`StartConfig`; standing start, ``vx = speed`` = 0
    by default): ``"regions"`` (default, the paper's): car i gets start region ``order[i]`` (a
    random permutation unless given), R1 the front-most ending at ``s0`` = 3 m, each region
    0.4 m long and 0.6 m behind the previous one, at a uniform position in it and a random
    lateral offset of at most ``lateral_jitter`` of the usable half width; ``"grid"``: two
    columns behind ``s0``, car_0 on pole, rows ``grid_gap`` m apart; ``"random"``: anywhere
    on the track, neighbours at least ``min_gap`` m apart (equal slots at a random rotation,
    jittered, cars in a random order). Heading, ``vy`` and ``omega`` start at zero.

    **Episode end**: truncation after ``max_cycles`` steps (default 500 = 50 s); with ``laps``
    set, termination of every agent when the first car completes that many laps (the line is
    the start position of the front-most car).

    **Info** (per agent): ``contact`` and ``off_track`` (rule applied this step), ``laps``
    (completed), ``progress`` (m driven since the start), ``substeps`` (RK4 sub-steps used),
    ``contacts`` and ``off_tracks`` (counts so far).

    **Arguments**: ``track`` (name for :func:`racing_env.tracks.make_track` or a
    :class:`Track`, default ``"default"``), ``n_cars`` (3), ``max_cycles`` (500), ``laps``
    (None), ``start`` (``"regions"``, ``"grid"`` or ``"random"``, or a :class:`StartConfig`),
    ``vehicle`` (:class:`VehicleParams`), ``rules`` (:class:`RulesConfig`), ``config`` (a full
    :class:`RaceConfig`; the other keywords override its fields), ``render_mode``
    (``"human"`` or ``"rgb_array"``).

    **Reset options**: ``{"n_cars": int, "start": mode or StartConfig, "order": list}`` where
    ``order[i]`` is the start region of car i (0 = R1, the front-most region).

    **Version History** (``metadata["name"]``; the Gymnasium id ``alpha_racer/HeadToHead-vN``
    carries the same number):

    * v2: contact keeps the bodies apart (:func:`racing_env.simulator._separate`). After
      every RK4 sub-step of a period with contact, no car may overlap, or be beyond, a car
      that it is not laterally clear of (``|n_i - n_j| < contact_dn``): a bump from behind
      puts the rear car back to ``contact_ds`` behind the front car and limits its ``vx`` to
      the front car's; a bump from the side pushes the two apart sideways, half each. In v1
      a car at full throttle could push through a stopped car in a few steps (the speed
      factors slowed it but never stopped it); in v2 a car passes another only through free
      space beside it. The speed factors are the paper's, as before, and a race without
      contact is the same as in v1 bit for bit.
    * v1: contact is checked over the whole control period (the relative motion of each pair
      is swept between RK4 sub-step points) and applied at the first moment of contact, so a
      car can no longer drive through another unnoticed; the car behind *at that moment* gets
      ``rear_factor``. Random starts are evenly spaced slots with jitter (bounded time).
      Out-of-range actions, ``+-inf`` included, are clipped; misshapen actions, actions for
      unknown agents and NaN raise ``ValueError``. The built-in raceline follower (the
      Gymnasium env's default opponents) drives the racing line's new speed profile: the car's
      own g-g-v envelope (:mod:`racing_env.envelope`) instead of a point mass at 0.85 g.
    * v0: initial version. Contact was checked only at the end of each 0.1 s step (a faster
      car could pass through a slower one within a step, and the car that had been hit could
      get the rear factor); not kept.
    """

    metadata = {"name": "alpha_racer_v2", "render_modes": ["human", "rgb_array"],
                "render_fps": 10, "is_parallelizable": True}

    def __init__(self, track: "str | Track" = "default", n_cars: int | None = None,
                 max_cycles: int | None = None, laps: int | None = None,
                 start: "str | StartConfig | None" = None, vehicle: VehicleParams | None = None,
                 rules: RulesConfig | None = None, config: RaceConfig | None = None,
                 render_mode: str | None = None):
        cfg = config or RaceConfig()
        changes = {}
        if n_cars is not None:
            changes["n_cars"] = n_cars
        if max_cycles is not None:
            changes["max_cycles"] = max_cycles
        if laps is not None:
            changes["laps"] = laps
        if start is not None:
            changes["start"] = _start_config(start, cfg.start)
        if vehicle is not None:
            changes["vehicle"] = vehicle
        if rules is not None:
            changes["rules"] = rules
        cfg = cfg.with_(**changes) if changes else cfg
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, "
                             f"got {render_mode!r}")
        self.render_mode = render_mode
        self.core = BatchedRaces(track, cfg, n_races=1)
        self.track = self.core.track
        self._renderer = None
        self._viewer = None
        self._was_reset = False
        self.np_random, self.np_random_seed = seeding.np_random()
        self._set_agents()

    # ------------------------------------------------------------------ spaces
    def _set_agents(self):
        n = self.core.n_cars
        self.possible_agents = [f"car_{i}" for i in range(n)]
        self.agents = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        lo, hi = self.core.observation_bounds()
        self._obs_spaces = {a: spaces.Box(lo, hi, dtype=np.float32) for a in self.possible_agents}
        self._act_spaces = {a: spaces.Box(-1.0, 1.0, (2,), dtype=np.float32) for a in self.possible_agents}
        slo, shi = self.core.state_bounds()
        self.state_space = spaces.Box(np.tile(np.maximum(slo, -1e9), n).astype(np.float32),
                                      np.tile(np.minimum(shi, 1e9), n).astype(np.float32),
                                      dtype=np.float32)
        self._actions = np.zeros((1, n, 2))

    def observation_space(self, agent):
        return self._obs_spaces[agent]

    def action_space(self, agent):
        return self._act_spaces[agent]

    @property
    def config(self) -> RaceConfig:
        return self.core.config

    # ------------------------------------------------------------------ API
    def reset(self, seed=None, options=None):
        options = options or {}
        unknown = set(options) - {"n_cars", "start", "order"}
        if unknown:  # the PettingZoo checkers pass arbitrary options; ignore them loudly
            import gymnasium
            gymnasium.logger.warn(f"ignoring unknown reset options {sorted(unknown)}; "
                                  f"known: n_cars, start, order")
        if "n_cars" in options and options["n_cars"] != self.core.n_cars:
            self.core.set_n_cars(options["n_cars"])
            self._set_agents()
        start = _start_config(options["start"], self.config.start) if "start" in options else None
        if seed is not None:
            self.np_random, self.np_random_seed = seeding.np_random(seed)
        obs = self.core.reset(seed=seed, order=options.get("order"), start=start)
        self._was_reset = True
        self.agents = list(self.possible_agents)
        if self.render_mode == "human":
            self.render()
        infos = self._infos()
        return ({a: obs[0, i] for i, a in enumerate(self.agents)},
                {a: infos[i] for i, a in enumerate(self.agents)})

    def step(self, actions):
        if not self.agents:
            if not self._was_reset:
                raise RuntimeError("step() called before reset(); call reset() first")
            raise RuntimeError("step() called on a finished episode; call reset() first")
        unknown = [a for a in actions if a not in self.agents]
        if unknown:
            raise ValueError(f"actions for unknown agents {unknown}; the live agents are {self.agents}")
        acts = self._actions
        for a in self.agents:
            if a not in actions:
                raise ValueError(f"missing action for {a}; every live agent acts each step")
            act = np.asarray(actions[a], dtype=np.float64)
            if act.shape != (2,):
                raise ValueError(f"action of {a} must have shape (2,) [throttle, steering], "
                                 f"got shape {act.shape}: {actions[a]!r}")
            if np.isnan(act).any():
                raise ValueError(f"action of {a} is NaN: {act.tolist()}")
            acts[0, self._index[a]] = act
        obs, rew, term, trunc = self.core.step(acts)
        term_b, trunc_b = bool(term[0]), bool(trunc[0]) and not bool(term[0])
        agents = self.agents
        rew = rew[0].tolist()
        infos = self._infos()
        observations = {a: obs[0, self._index[a]] for a in agents}
        rewards = {a: rew[self._index[a]] for a in agents}
        terminations = dict.fromkeys(agents, term_b)
        truncations = dict.fromkeys(agents, trunc_b)
        infos = {a: infos[self._index[a]] for a in agents}
        if term_b or trunc_b:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return observations, rewards, terminations, truncations, infos

    def _infos(self) -> list[dict]:
        """Per-car info dicts (see the class docstring), in car order."""
        return self.core.infos(0, np.arange(self.core.n_cars))

    def state(self) -> np.ndarray:
        return self.core.state[0].reshape(-1).astype(np.float32)

    # ------------------------------------------------------------------ rendering
    def render(self):
        if self.render_mode is None:
            import gymnasium
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode=...")
            return None
        frame = self.render_frame()
        if self.render_mode == "rgb_array":
            return frame
        from .render import HumanViewer
        if self._viewer is None:
            self._viewer = HumanViewer(title=self.metadata["name"])
        self._viewer.show(frame)
        return None

    def render_frame(self) -> np.ndarray:
        """RGB frame (H, W, 3) uint8 of the current race, whatever the render mode."""
        if self._renderer is None:
            from .raceline import get_raceline
            from .render import Renderer
            rl = get_raceline(self.track, self.config.vehicle)
            self._renderer = Renderer(self.track, vehicle=self.config.vehicle, raceline_xy=(rl.x, rl.y))
        c = self.core
        hud = [f"t = {c.t[0] * self.config.dt:5.1f} s"]
        order = np.argsort(-c.state[0, :, 0])
        hud += [f"P{k + 1} car_{i}  lap {c.laps[0, i]}" for k, i in enumerate(order)]
        return self._renderer.frame(c.state[0], hud=hud)

    def close(self):
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None


def _start_config(start, base: StartConfig) -> StartConfig:
    if isinstance(start, StartConfig):
        return start
    if isinstance(start, str):
        from dataclasses import replace
        return replace(base, mode=start)
    raise ValueError(f"start must be 'grid', 'regions', 'random' or a StartConfig, got {start!r}")


def parallel_env(**kwargs) -> RacingParallelEnv:
    """Make the PettingZoo ParallelEnv (see :class:`RacingParallelEnv` for the arguments)."""
    return RacingParallelEnv(**kwargs)


def env(**kwargs):
    """Make the AEC version of :class:`RacingParallelEnv` (cars act in turn, step together)."""
    from pettingzoo.utils.conversions import parallel_to_aec
    return parallel_to_aec(RacingParallelEnv(**kwargs))


raw_env = RacingParallelEnv
