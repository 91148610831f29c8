"""What a self-play run is and where it stands: the :class:`SelfPlayConfig` (what to train),
the :class:`SelfPlayState` (its progress, ``state.json``) and the race it learns in
(:func:`race_config`). Self-play (:mod:`experiments.learning.selfplay`) and behaviour
cloning (:mod:`experiments.learning.imitation`) both read them."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

from experiments.infra.artifacts import write_json
from experiments.infra.checks import check_counts

VEC_ENVS = ("batched", "dummy", "subproc")
WARMUP_OPPONENTS = ("raceline", "initial")
INITS = ("random", "bc")
RACELINE_GRIP = (0.75, 0.8, 0.85, 0.7, 0.9, 0.65, 0.95)
RACELINE_MU = RACELINE_GRIP  # the old name (mu names the heading in the state)
"""Friction of the raceline followers standing in for untrained cars, by opponent slot."""
OFFTRACK_BAR = 0.05
BC_ALONE = {"orca": 0.0, "fullsize": 0.5}
"""The fraction of behaviour cloning's races that the learner drives alone, by vehicle class
(``SelfPlayConfig.bc_alone`` left unset). Alone, the policy sees the other cars as phantoms
half a lap behind (:func:`agents.observations.adapt_observation`), as in the solo evaluation.
On the 1:43 track those lie inside the range of progress differences the cars reach in a race
(the field spreads over laps of a 39 m track); on a full-scale circuit a 50 s race covers
under a third of a lap, so a policy cloned from races with others only has never seen them
(normalised to -14 standard deviations, clipped at -10) and barely drives alone."""


@dataclass(frozen=True)
class SelfPlayConfig:
    """What to train. Defaults: the paper's schedule and PPO settings."""

    n_cars: int = 3
    cycles: int = 33
    steps_per_turn: int = 100_000
    n_envs: int = 8
    batch_size: int = 1024
    n_epochs: int = 5
    learning_rate: float = 5e-4
    gamma: float = 0.99
    n_steps: int = 2048
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    net_arch: tuple = (64, 64)
    track: str = "default"
    max_cycles: int = 500
    start: str = "regions"
    seed: int = 0
    vec_env: str = "batched"
    warmup_opponent: str = "raceline"
    norm_reward: bool = True
    checkpoint_every: int = 1
    eval_races: int = 3
    mpc_reference: bool = True
    init: str = "random"
    bc_steps: int = 50_000
    bc_rounds: int = 3
    bc_epochs: int = 10
    bc_noise: float = 0.3
    bc_log_std: float = -1.0
    bc_alone: float | None = None  # the fraction of BC races driven alone; None: the class's
    # (BC_ALONE: 0 orca, 0.5 fullsize), stored resolved
    vehicle_class: str = "orca"  # "orca" (the paper's 1:43 cars) or "fullsize"
    wake: float | None = None  # the wake's strength; None: the class's (0 orca, 1 fullsize),
    # stored resolved

    def __post_init__(self):
        object.__setattr__(self, "net_arch", tuple(self.net_arch))
        self._check_class()
        check_counts(
            self,
            (
                "cycles",
                "steps_per_turn",
                "n_envs",
                "batch_size",
                "n_epochs",
                "n_steps",
                "max_cycles",
                "checkpoint_every",
                "eval_races",
                "bc_steps",
                "bc_rounds",
                "bc_epochs",
            ),
        )
        if not (isinstance(self.n_cars, (int, np.integer)) and 2 <= self.n_cars <= 8):
            raise ValueError(
                f"SelfPlayConfig.n_cars must be an integer in 2..8, got {self.n_cars!r}"
            )
        for name, lo, hi in (
            ("learning_rate", 0.0, 1.0),
            ("gamma", 0.0, 1.0),
            ("gae_lambda", 0.0, 1.0),
            ("clip_range", 0.0, 10.0),
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and lo < v <= hi):
                raise ValueError(f"SelfPlayConfig.{name} must be in ({lo}, {hi}], got {v!r}")
        if not (isinstance(self.ent_coef, (int, float)) and self.ent_coef >= 0):
            raise ValueError(f"SelfPlayConfig.ent_coef must be >= 0, got {self.ent_coef!r}")
        if self.batch_size > self.n_steps * self.n_envs:
            raise ValueError(
                f"SelfPlayConfig.batch_size {self.batch_size} exceeds a rollout of "
                f"n_steps * n_envs = {self.n_steps * self.n_envs} steps"
            )
        if not self.net_arch or not all(
            isinstance(h, (int, np.integer)) and h >= 1 for h in self.net_arch
        ):
            raise ValueError(
                f"SelfPlayConfig.net_arch must be positive layer widths, got {self.net_arch!r}"
            )
        if self.vec_env not in VEC_ENVS:
            raise ValueError(
                f"SelfPlayConfig.vec_env must be one of {VEC_ENVS}, got {self.vec_env!r}"
            )
        if self.warmup_opponent not in WARMUP_OPPONENTS:
            raise ValueError(
                f"SelfPlayConfig.warmup_opponent must be one of {WARMUP_OPPONENTS}, "
                f"got {self.warmup_opponent!r}"
            )
        if self.init not in INITS:
            raise ValueError(f"SelfPlayConfig.init must be one of {INITS}, got {self.init!r}")
        if not (isinstance(self.bc_noise, (int, float)) and 0 <= self.bc_noise <= 2):
            raise ValueError(f"SelfPlayConfig.bc_noise must be in [0, 2], got {self.bc_noise!r}")
        if not (
            isinstance(self.bc_alone, (int, float))
            and not isinstance(self.bc_alone, bool)
            and 0 <= self.bc_alone <= 1
        ):
            raise ValueError(f"SelfPlayConfig.bc_alone must be in [0, 1], got {self.bc_alone!r}")
        if not (isinstance(self.bc_log_std, (int, float)) and -5 <= self.bc_log_std <= 1):
            raise ValueError(
                f"SelfPlayConfig.bc_log_std must be in [-5, 1], got {self.bc_log_std!r}"
            )
        from racing_env.config import START_MODES

        if self.start not in START_MODES:
            raise ValueError(
                f"SelfPlayConfig.start must be one of {START_MODES}, got {self.start!r}"
            )

    def _check_class(self) -> None:
        """Check ``vehicle_class`` and resolve ``wake`` (None: the class's) and, at full size,
        the track ``"default"`` (the class's circuit, ``tumftm:Monza``) in place; a built-in
        1:43 track at full size is refused."""
        from experiments.evaluation.bench_config import class_wake
        from racing_env.class_config import default_track
        from racing_env.tracks import BUILTIN

        try:
            object.__setattr__(self, "wake", class_wake(self.vehicle_class, self.wake))
        except ValueError as exc:
            raise ValueError(f"SelfPlayConfig.{exc}") from None
        if self.bc_alone is None:
            object.__setattr__(self, "bc_alone", BC_ALONE[self.vehicle_class])
        if self.vehicle_class == "orca":
            return
        if self.track == "default":
            object.__setattr__(self, "track", default_track(self.vehicle_class))
        elif self.track in BUILTIN:
            raise ValueError(
                f"SelfPlayConfig.track {self.track!r} is a 1:43 track of the 'orca' class; "
                f"vehicle_class {self.vehicle_class!r} races on full-scale circuits: "
                f"tumftm:NAME or random:SEED (default {default_track(self.vehicle_class)!r})"
            )

    @property
    def turns(self) -> int:
        return self.cycles * self.n_cars

    @property
    def rollout(self) -> int:
        return self.n_steps * self.n_envs

    @property
    def steps_per_turn_actual(self) -> int:
        """Env steps of one turn: whole rollouts."""
        return math.ceil(self.steps_per_turn / self.rollout) * self.rollout

    def to_dict(self) -> dict:
        """JSON-ready; ``vehicle_class`` and ``wake`` only when they are not the paper's world
        (the 1:43 class without a wake), and ``bc_alone`` not when it is the ORCA class's
        (0), so an ORCA run's config is what it always was."""
        from experiments.evaluation.bench_config import drop_default_class

        d = asdict(self)
        d["net_arch"] = list(self.net_arch)
        if self.vehicle_class == "orca" and self.bc_alone == BC_ALONE["orca"]:
            del d["bc_alone"]  # the ORCA class's, as every run before it was a setting
        return drop_default_class(d)

    @classmethod
    def from_dict(cls, d: dict) -> SelfPlayConfig:
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown SelfPlayConfig fields {sorted(unknown)}")
        return cls(**d)


@dataclass
class SelfPlayState:
    """A run's progress, stored as ``state.json`` (:meth:`to_dict` / :meth:`from_dict`).

    ``turn`` (turns finished), ``turn_steps`` (env steps done in the current turn),
    ``current`` (its latest in-turn checkpoint, relative to the run folder, or None),
    ``total_steps`` (all turns), ``train_seconds`` / ``train_cpu_seconds`` (wall and CPU time
    of training [s]), ``cars`` (each car's latest turn-end checkpoint or None),
    ``trained_turns`` (turns each car has had), ``evals`` (one row per evaluation, see
    ``evals.csv``), ``train_curve`` (the learner's mean episode return after each rollout),
    ``mpc_reference`` (the MPC alone, or None), ``bc_init`` (the behaviour-cloned start, or
    None), ``bc_cpu_seconds`` (its CPU time [s], or None) and ``done``."""

    turn: int = 0
    turn_steps: int = 0
    current: str | None = None
    total_steps: int = 0
    train_seconds: float = 0.0
    train_cpu_seconds: float = 0.0
    cars: list = field(default_factory=list)
    trained_turns: list = field(default_factory=list)
    evals: list = field(default_factory=list)
    train_curve: list = field(default_factory=list)
    mpc_reference: dict | None = None
    bc_init: str | None = None
    bc_cpu_seconds: float | None = None
    done: bool = False

    @classmethod
    def new(cls, cfg: SelfPlayConfig) -> SelfPlayState:
        """The state of a run that has not started: no checkpoint for any of the cars."""
        return cls(cars=[None] * cfg.n_cars, trained_turns=[0] * cfg.n_cars)

    def to_dict(self) -> dict:
        """JSON-ready: every field by name."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict, cfg: SelfPlayConfig | None = None) -> SelfPlayState:
        """From :meth:`to_dict`'s output or an older ``state.json`` (fields it lacks, as
        ``train_cpu_seconds`` and ``bc_cpu_seconds`` in runs before they were recorded, take
        their defaults). With ``cfg``, the lists of cars must have ``cfg.n_cars`` entries.
        Unknown keys are a ValueError."""
        if not isinstance(d, dict):
            raise ValueError(f"a self-play state must be a JSON object, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(
                f"unknown self-play state fields {sorted(unknown)}; expected some of "
                f"{sorted(known)}"
            )
        state = cls(**d)
        if cfg is not None:
            if len(state.cars) != cfg.n_cars or len(state.trained_turns) != cfg.n_cars:
                raise ValueError(
                    f"self-play state has {len(state.cars)} cars and "
                    f"{len(state.trained_turns)} turn counts, expected "
                    f"n_cars={cfg.n_cars} of each"
                )
        return state

    @classmethod
    def load(cls, path: Path, cfg: SelfPlayConfig) -> SelfPlayState:
        """``path`` (a ``state.json``) if it exists, else a new state."""
        path = Path(path)
        if not path.exists():
            return cls.new(cfg)
        return cls.from_dict(json.loads(path.read_text()), cfg)

    def save(self, path: Path) -> None:
        """Write the state to ``path`` atomically."""
        write_json(path, self.to_dict())


def race_config(cfg: SelfPlayConfig):
    """The :class:`~racing_env.RaceConfig` of the run's races: the class's
    (:func:`racing_env.class_config.race_config_for`: the paper's for ``"orca"``; the car,
    rules and start scaled to the full-size car) with the run's wake, cars, steps and start
    mode."""
    from dataclasses import replace

    from racing_env.class_config import race_config_for

    base = race_config_for(cfg.vehicle_class, wake=cfg.wake)
    return base.with_(
        n_cars=cfg.n_cars, max_cycles=cfg.max_cycles, start=replace(base.start, mode=cfg.start)
    )
