"""PettingZoo ParallelEnv of N cars racing on a track (the paper's game, section 2)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from .class_config import class_race
from .config import RaceConfig, RulesConfig, StartConfig
from .core import BatchedRaces, start_states
from .track import Track
from .vehicle import VehicleParams
from .vehicles.fullsize import FullSizeParams

if TYPE_CHECKING:
    from .render import HumanViewer, Renderer

RESET_OPTIONS = ("n_cars", "start", "order")
#: Width [car lengths] of the followed view a class other than the paper's is rendered in.
FOLLOW_VIEW_LENGTHS = 40.0


def check_reward_options(offtrack_penalty: float, terminate_off_track: bool) -> tuple[float, bool]:
    """Validated ``(offtrack_penalty, terminate_off_track)`` of an env (see
    :class:`RacingParallelEnv`): a finite penalty >= 0 [m per step off track] and a bool."""
    if (
        isinstance(offtrack_penalty, (bool, np.bool_))
        or not isinstance(offtrack_penalty, (int, float, np.integer, np.floating))
        or not np.isfinite(offtrack_penalty)
        or offtrack_penalty < 0
    ):
        raise ValueError(
            f"offtrack_penalty must be a finite number >= 0 (metres of reward taken "
            f"per step off track), got {offtrack_penalty!r}"
        )
    if not isinstance(terminate_off_track, (bool, np.bool_)):
        raise ValueError(f"terminate_off_track must be True or False, got {terminate_off_track!r}")
    return float(offtrack_penalty), bool(terminate_off_track)


class RacingParallelEnv(ParallelEnv):
    """N cars race on a closed track; each wants to gain progress on the leading opponent.

    The cars follow the paper's dynamic bicycle model with Pacejka tyres in the Frenet frame
    (:mod:`racing_env.vehicle`), integrated with adaptive RK4 sub-steps inside each 0.1 s
    control period, under the paper's contact and off-track rules (:class:`RulesConfig`).
    With ``vehicle_class="fullsize"`` they are full-size single-seaters
    (:mod:`racing_env.vehicles.fullsize`) on a full-scale circuit (default Monza), with the
    rules at their size and two of their own (a car off the track rejoins it, a pair of cars
    in touch is slowed once, not every period) and the wake (:mod:`racing_env.wake`: tow
    and dirty air) on (:mod:`racing_env.class_config`).

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

    Scales, for normalisation (ORCA, default track, 38.9 m; default vehicle, top speed 4.2 m/s):
    own ``s`` in ``[0, L)``; ``n`` within the walls (+-0.40 m; the track edges are at
    +-0.25 m); ``mu`` in ``[-pi, pi]``, a few tenths on track; ``vx`` 0..4.2 m/s; ``vy`` and
    ``omega`` mostly within +-1 m/s and +-6 rad/s; relative ``s`` a few metres in a close race
    and at most a lap or two in 50 s; curvature within +-1.3 1/m. The bounds of the ``Box``
    (:meth:`racing_env.BatchedRaces.observation_bounds`) are guaranteed, not typical: own
    ``s``, ``n``, ``mu`` and the curvature are tight, ``vx`` and ``vy`` within 1.5 x top speed
    + 1 m/s, ``omega`` within +-100 rad/s, relative ``s`` within the +-1e4 m at which it is
    clipped (no tighter bound holds for every race: contact can push cars back). Normalise
    with running statistics (SB3's ``VecNormalize``), not with the bounds. The full-size class
    (Monza, 5.79 km) has the same layout in the same SI units, at its own scale: own ``s``
    0..5791 m, ``n`` on track within +-3.6..6.3 m (the walls 5 m beyond the edges: the bound
    +-11.3 m), ``vx`` 0..66 m/s in clean air and up to 91 m/s right behind another car (the
    bound: 1.5 x that + 1 = 137 m/s), ``vy`` and ``omega`` a few m/s and tenths of rad/s
    (bounds as ORCA's), relative ``s`` tens to hundreds of metres, clipped at +-3.9e5 m
    (:func:`racing_env.core.s_clip`: the ORCA bound times the length ratio, 67 laps),
    curvature within +-0.12 1/m.

    ``state()`` returns the global joint state: every car's ``(s, n, mu, vx, vy, omega)`` with
    unwrapped ``s``, flattened in agent order (``6 N`` float32).

    **Reward**: per step, the change of ``s_i - max_{j != i} s_j`` [m] on unwrapped arc
    length (the paper's relative progress; ``s_i`` alone when N = 1). Crossing the start/finish
    line causes no jump and driving backwards always costs reward. This is the paper's reward,
    the default. Off track costs nothing in it beyond the rule's slow-down (half the speed,
    re-aligned), so a learner may find riding outside the edge safe; ``offtrack_penalty`` (m
    per step, default 0) subtracts that much from a car's reward on every step its off-track
    rule applies.

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
    the start position of the front-most car); with ``terminate_off_track=True`` (default
    False, the paper's rule), termination of every agent at the first step on which any car's
    off-track rule applies.

    **Info** (per agent): ``contact`` and ``off_track`` (rule applied this step), ``laps``
    (completed), ``progress`` (m driven since the start), ``substeps`` (RK4 sub-steps used),
    ``contacts`` and ``off_tracks`` (counts so far), ``drag_factor`` and ``downforce_factor``
    (the wake's factors held over this step, 1.0 in clean air or with ``wake=0``).

    **Arguments**: ``track`` (name for :func:`racing_env.tracks.make_track` or a
    :class:`Track`, default ``"default"``), ``n_cars`` (3), ``max_cycles`` (500), ``laps``
    (None), ``start`` (``"regions"``, ``"grid"`` or ``"random"``, or a :class:`StartConfig`),
    ``vehicle`` (:class:`VehicleParams`), ``rules`` (:class:`RulesConfig`), ``config`` (a full
    :class:`RaceConfig`; the other keywords override its fields), ``render_mode``
    (``"human"`` or ``"rgb_array"``), ``offtrack_penalty`` (0.0) and ``terminate_off_track``
    (False): the reward and episode-end options above (not part of :class:`RaceConfig`; the
    defaults are the paper's game), ``vehicle_class`` (``"orca"`` or ``"fullsize"``; default:
    the class of ``vehicle``, ``config`` or a :class:`Track`, else ``"orca"``): a track name
    is built at the class's scale (default track ``"default"`` / ``"tumftm:Monza"``), and
    without ``config`` the vehicle, rules, start and preview are the class's
    (:func:`racing_env.class_config.race_config_for`); a track, vehicle or config of another
    class is a ``ValueError``; ``wake`` (the wake's strength, ``RaceConfig.wake``; default
    the class's: 0 for ORCA, 1 full size).

    **Reset options**: ``{"n_cars": int, "start": mode or StartConfig, "order": list}`` where
    ``order[i]`` is the start region of car i (0 = R1, the front-most region). All options are
    checked before anything changes: a reset that raises leaves the env as it was.

    **Version History** (``metadata["name"]``; the Gymnasium id ``alpha_racer/HeadToHead-vN``
    carries the same number):

    * v2: contact keeps the bodies apart (:func:`racing_env.contact._separate`). After
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

    metadata: dict[str, Any] = {
        "name": "alpha_racer_v2",
        "render_modes": ["human", "rgb_array"],
        "render_fps": 10,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        track: str | Track | None = None,
        n_cars: int | None = None,
        max_cycles: int | None = None,
        laps: int | None = None,
        start: str | StartConfig | None = None,
        vehicle: VehicleParams | FullSizeParams | None = None,
        rules: RulesConfig | None = None,
        config: RaceConfig | None = None,
        render_mode: str | None = None,
        offtrack_penalty: float = 0.0,
        terminate_off_track: bool = False,
        vehicle_class: str | None = None,
        wake: float | None = None,
    ):
        cfg, track = class_race(vehicle_class, track, config, vehicle, wake)
        changes: dict[str, Any] = {}
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
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        self.offtrack_penalty, self.terminate_off_track = check_reward_options(
            offtrack_penalty, terminate_off_track
        )
        self.render_mode = render_mode
        self.core = BatchedRaces(track, cfg, n_races=1)
        self.track = self.core.track
        self._renderer: Renderer | None = None
        self._viewer: HumanViewer | None = None
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
        self._act_spaces = {
            a: spaces.Box(-1.0, 1.0, (2,), dtype=np.float32) for a in self.possible_agents
        }
        slo, shi = self.core.state_bounds()
        self.state_space = spaces.Box(
            np.tile(np.maximum(slo, -1e9), n).astype(np.float32),
            np.tile(np.minimum(shi, 1e9), n).astype(np.float32),
            dtype=np.float32,
        )
        self._actions = np.zeros((1, n, 2))

    def observation_space(self, agent: str) -> spaces.Box:
        """The observation space of one agent.

        Parameters
        ----------
        agent : str
            ``"car_0"`` .. ``"car_{N-1}"`` (any of ``possible_agents``).

        Returns
        -------
        gymnasium.spaces.Box
            float32 of shape ``(6 N + n_preview,)``: own Frenet state, the other cars relative
            to this one, the curvature preview (layout and scales in the class docstring). The
            bounds are the envelope every observation stays in, not a scale to normalise by.
        """
        return self._space(self._obs_spaces, agent)

    def action_space(self, agent: str) -> spaces.Box:
        """The action space of one agent (``agent`` as in :meth:`observation_space`).

        Returns
        -------
        gymnasium.spaces.Box
            ``Box(-1, 1, (2,), float32)``: ``[throttle, steering]``, mapped affinely onto the
            vehicle's ``[d_min, d_max]`` and ``[-delta_max, delta_max]`` rad (positive left).
            The env applies no steering-rate bound (``VehicleParams.delta_rate_max`` binds
            the MPC agents only): the steering angle may jump within one step.
        """
        return self._space(self._act_spaces, agent)

    def _space(self, table: dict, agent) -> spaces.Box:
        try:
            return table[agent]
        except (KeyError, TypeError):
            raise ValueError(
                f"unknown agent {agent!r}; the agents are {self.possible_agents}"
            ) from None

    @property
    def config(self) -> RaceConfig:
        return self.core.config

    # ------------------------------------------------------------------ API
    def reset(
        self, seed: int | None = None, options: dict | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        """Start a new race.

        Parameters
        ----------
        seed : int, optional
            Seeds the start positions (same seed, same starts); None continues the current
            random stream.
        options : dict, optional
            ``n_cars`` (1..8: changes the agents and the spaces), ``start`` (``"regions"``,
            ``"grid"``, ``"random"`` or a :class:`StartConfig`, for this race only) and
            ``order`` (``order[i]``: start region of car i, 0 = R1, in ``"regions"`` mode).
            Unknown keys are ignored with a warning (PettingZoo's checkers pass some).

        Returns
        -------
        observations : dict[str, numpy.ndarray]
            Per agent the first observation (see :meth:`observation_space`).
        infos : dict[str, dict]
            Per agent the info dict (keys in the class docstring; counts at zero).

        Raises
        ------
        ValueError
            On a bad option (a car count outside 1..8, an unknown start mode, an order that is
            not a permutation, cars that do not fit on the track). Every option is checked
            before any state changes, so after the error the env is as it was.
        """
        return self._reset_checked(seed, *_check_reset_options(options, self.core))

    def _reset_checked(
        self, seed: int | None, n_cars: int, start: StartConfig | None, order
    ) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        """:meth:`reset` with options already checked by :func:`_check_reset_options`
        (which placed the cars once on a throwaway generator): the race is started here."""
        if n_cars != self.core.n_cars:
            self.core.set_n_cars(n_cars)
            self._set_agents()
        if seed is not None:
            self.np_random, self.np_random_seed = seeding.np_random(seed)
        obs = self.core.reset(seed=seed, order=order, start=start)
        self._was_reset = True
        self.agents = list(self.possible_agents)
        if self.render_mode == "human":
            self.render()
        infos = self._infos()
        return (
            {a: obs[0, i] for i, a in enumerate(self.agents)},
            {a: infos[i] for i, a in enumerate(self.agents)},
        )

    def step(
        self, actions: dict
    ) -> tuple[
        dict[str, np.ndarray], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict]
    ]:
        """Advance the race by one control period (0.1 s) with one action per live agent.

        Parameters
        ----------
        actions : dict[str, array_like]
            For every live agent (``self.agents``), ``[throttle, steering]`` in ``[-1, 1]``
            (see :meth:`action_space`; values outside are clipped).

        Returns
        -------
        observations, rewards, terminations, truncations, infos : dict
            Per live agent: the new observation; the reward (the change of relative progress
            ``s_i - max_{j != i} s_j`` [m], minus ``offtrack_penalty`` if the car is off
            track); ``terminated`` (``laps`` completed by the first car, or a car off track
            with ``terminate_off_track``); ``truncated`` (``max_cycles`` reached); the info
            dict (contact and off-track flags and counts, laps, progress, sub-steps). When
            the episode ends, ``agents`` becomes empty.

        Raises
        ------
        RuntimeError
            Before the first :meth:`reset`, or after the episode ended.
        ValueError
            An action missing for a live agent, given for an unknown one, of another shape
            than ``(2,)``, or NaN (naming the agent).
        """
        if not self.agents:
            if not self._was_reset:
                raise RuntimeError("step() called before reset(); call reset() first")
            raise RuntimeError("step() called on a finished episode; call reset() first")
        unknown = [a for a in actions if a not in self.agents]
        if unknown:
            raise ValueError(
                f"actions for unknown agents {unknown}; the live agents are {self.agents}"
            )
        acts = self._actions
        for a in self.agents:
            if a not in actions:
                raise ValueError(f"missing action for {a}; every live agent acts each step")
            act = np.asarray(actions[a], dtype=np.float64)
            if act.shape != (2,):
                raise ValueError(
                    f"action of {a} must have shape (2,) [throttle, steering], "
                    f"got shape {act.shape}: {actions[a]!r}"
                )
            if np.isnan(act).any():
                raise ValueError(f"action of {a} is NaN: {act.tolist()}")
            acts[0, self._index[a]] = act
        obs, rew, term, trunc = self.core.step(acts)
        term_b = bool(term[0])
        if self.offtrack_penalty or self.terminate_off_track:
            off = self.core.offtrack[0].astype(bool)
            rew = rew - self.offtrack_penalty * off[None]
            term_b = term_b or (self.terminate_off_track and bool(off.any()))
        trunc_b = bool(trunc[0]) and not term_b
        agents = self.agents
        rew = rew[0].tolist()
        car_infos = self._infos()
        observations = {a: obs[0, self._index[a]] for a in agents}
        rewards = {a: rew[self._index[a]] for a in agents}
        terminations = dict.fromkeys(agents, term_b)
        truncations = dict.fromkeys(agents, trunc_b)
        infos = {a: car_infos[self._index[a]] for a in agents}
        if term_b or trunc_b:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return observations, rewards, terminations, truncations, infos

    def _infos(self) -> list[dict]:
        """Per-car info dicts (see the class docstring), in car order."""
        return self.core.infos(0, np.arange(self.core.n_cars))

    def _require_reset(self, what: str) -> None:
        if not self._was_reset:
            raise RuntimeError(
                f"{what} called before reset(): there is no race yet; call reset() first"
            )

    def state(self) -> np.ndarray:
        """The global joint state of the race (for centralised critics).

        Returns
        -------
        numpy.ndarray
            float32 of shape ``(6 N,)``: every car's ``(s, n, mu, vx, vy, omega)`` in agent
            order, ``s`` unwrapped (it keeps growing across laps); bounds in ``state_space``.

        Raises
        ------
        RuntimeError
            Before the first :meth:`reset`.
        """
        self._require_reset("state()")
        return self.core.state[0].reshape(-1).astype(np.float32)

    # ------------------------------------------------------------------ rendering
    def render(self) -> np.ndarray | None:
        """Draw the race in the ``render_mode`` given to the constructor.

        Returns
        -------
        numpy.ndarray or None
            ``"rgb_array"``: the frame, ``(H, W, 3)`` uint8 (track, racing line, cars, a
            head-up display of time, positions and laps). ``"human"``: shows it in a window
            and returns None. Without a render mode: warns and returns None.

        Raises
        ------
        RuntimeError
            Before the first :meth:`reset` (there is no race to draw).
        """
        if self.render_mode is None:
            import gymnasium

            gymnasium.logger.warn("render() called without a render_mode; pass render_mode=...")
            return None
        self._require_reset("render()")
        frame = self.render_frame()
        if self.render_mode == "rgb_array":
            return frame
        from .render import HumanViewer

        if self._viewer is None:
            self._viewer = HumanViewer(title=self.metadata["name"])
        self._viewer.show(frame)
        return None

    def render_frame(self, follow: int | None = None) -> np.ndarray:
        """RGB frame (H, W, 3) uint8 of the current race, whatever the render mode. A class
        other than the paper's (circuits of kilometres) is drawn in a view
        :data:`FOLLOW_VIEW_LENGTHS` car lengths across that follows car ``follow`` (default
        the lead car); the paper's class shows the whole track."""
        self._require_reset("render_frame()")
        if self._renderer is None:
            from .raceline import get_raceline
            from .render import Renderer

            rl = get_raceline(self.track, self.config.vehicle)
            view = None
            if self.config.vehicle_class != "orca":
                view = FOLLOW_VIEW_LENGTHS * self.config.vehicle.length
            self._renderer = Renderer(
                self.track, vehicle=self.config.vehicle, raceline_xy=(rl.x, rl.y), view_m=view
            )
        c = self.core
        hud = [f"t = {c.t[0] * self.config.dt:5.1f} s"]
        order = np.argsort(-c.state[0, :, 0])
        hud += [f"P{k + 1} car_{i}  lap {c.laps[0, i]}" for k, i in enumerate(order)]
        if self._renderer.view_m is not None:  # a followed view: the speeds, the gaps
            lead = c.state[0, order[0], 0]
            hud = hud[:1] + [
                f"P{k + 1} car_{i}  {c.state[0, i, 3] * 3.6:3.0f} km/h  "
                + (f"+{lead - c.state[0, i, 0]:.0f} m" if k else "")
                for k, i in enumerate(order)
            ]
        return self._renderer.frame(c.state[0], hud=hud, follow=follow)

    def close(self) -> None:
        """Close the ``"human"`` window if one is open (the env can still be reset and used)."""
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None


def relative_progress(env: RacingParallelEnv, car: int = 0) -> float:
    """Car ``car``'s progress [m] minus the best other car's (its own progress when alone)."""
    s = env.core.state[0, :, 0] - env.core.s_line[0]
    others = np.delete(s, car)
    return float(s[car] - (others.max() if others.size else 0.0))


def _check_reset_options(options: dict | None, core: BatchedRaces, known=RESET_OPTIONS):
    """``(n_cars, start, order)`` of a reset's ``options``, every one checked (by a dry run of
    the start on a throwaway generator) before the caller changes anything: a car count
    outside 1..8, a bad start mode, an order that is not a permutation, or cars that do not
    fit raise ``ValueError`` with the env untouched. Unknown keys are warned about."""
    options = options or {}
    unknown = set(options) - set(known)
    if unknown:  # the PettingZoo checkers pass arbitrary options; ignore them loudly
        import gymnasium

        gymnasium.logger.warn(
            f"ignoring unknown reset options {sorted(unknown)}; known: {', '.join(known)}"
        )
    n_cars = options.get("n_cars", core.n_cars)
    cfg = core.config.with_(n_cars=n_cars) if n_cars != core.n_cars else core.config
    start = _start_config(options["start"], cfg.start) if "start" in options else None
    order = options.get("order")
    if order is not None:
        try:
            order = [int(o) for o in order]
        except (TypeError, ValueError):
            raise ValueError(
                f"start order must be a list of start-region indices, got {order!r}"
            ) from None
        if sorted(order) != list(range(cfg.n_cars)):
            raise ValueError(
                f"start order must be a permutation of 0..{cfg.n_cars - 1}, got {order}"
            )
    start_states(
        core.track,
        cfg.n_cars,
        start or cfg.start,
        cfg.vehicle.width,
        np.random.default_rng(0),
        order,
    )
    return cfg.n_cars, start, options.get("order")


def _check_learner_reset_options(options: dict | None, n_cars: int) -> dict:
    """The reset ``options`` of the one-learner envs (``start`` and ``order``; ``n_cars`` only
    as the race's own ``n_cars``: the opponents fix it), as a dict; any other key or another
    car count raises ``ValueError`` (the values are checked by :func:`_check_reset_options`, or
    by the race's own reset)."""
    options = dict(options or {})
    if "n_cars" in options and options["n_cars"] != n_cars:
        raise ValueError(
            f"reset option n_cars = {options['n_cars']!r}: the env races {n_cars} cars (the "
            f"learner and {n_cars - 1} opponents); make a new env to race another number"
        )
    unknown = set(options) - set(RESET_OPTIONS)
    if unknown:
        raise ValueError(f"unknown reset options {sorted(unknown)}; known: start, order")
    return options


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


def env(**kwargs) -> RacingParallelEnv:
    """Make the AEC version of :class:`RacingParallelEnv` (cars act in turn, step together)."""
    from pettingzoo.utils.conversions import parallel_to_aec

    return parallel_to_aec(RacingParallelEnv(**kwargs))


raw_env = RacingParallelEnv
