"""PPO self-play (the paper's RL baseline, appendix "Self-play RL training").

``alpha-racer selfplay --out runs/selfplay`` trains one stable-baselines3 ``PPO`` agent per car
by iterated self-play: the cars take turns learning, car ``turn mod n_cars`` for
``steps_per_turn`` env steps, while every other car is frozen at its latest policy. The
learning env is the registered Gymnasium env ``alpha_racer/HeadToHead-v2`` (one learner,
opponents embedded) vectorised over ``n_envs`` races; ``vec_env="batched"`` (default) runs the
same env as :class:`racing_env.vec_env.HeadToHeadVecEnv` (all races in one compiled step,
frozen opponents as batched numpy policies, race for race identical to ``HeadToHeadEnv``),
``"dummy"`` / ``"subproc"`` wrap ``gymnasium.make`` in SB3's ``DummyVecEnv`` /
``SubprocVecEnv``. Observations are normalised by SB3's ``VecNormalize`` (saved with every
checkpoint and used by the ``ppo`` agent); the reward is the env's relative progress
(change of ``s_i - max_{j != i} s_j``), normalised for the learner by ``VecNormalize``.

Defaults are the paper's: 3 cars, 33 cycles, 100k steps per turn, batch 1024, 5 epochs,
learning rate 5e-4, gamma 0.99, 8 parallel envs; the rest is SB3's standard PPO (rollouts of
``n_steps = 2048`` per env, GAE 0.95, clip 0.2, a 64-64 tanh MLP). A turn trains whole
rollouts, so it takes ``ceil(steps_per_turn / (n_steps n_envs))`` of them.

Curriculum (``warmup_opponent``): a car that has not had a turn yet has no policy worth
racing; with ``"raceline"`` (default) it is driven by a raceline follower until its first
turn (so car 0's first turn is against raceline followers, car 1's against car 0 and a
follower, ...); with ``"initial"`` it is its randomly initialised policy, as in plain self-play.

Output folder::

    config.json           schema version and the SelfPlayConfig (a resume must match it)
    state.json            progress: turn, steps, latest checkpoint of each car, evaluations
    checkpoints/          turn_TTT_car_K.zip at every turn end; in-turn checkpoints
                          (every ``checkpoint_every`` rollouts) until their turn is done
    logs/car_K/           TensorBoard event files and CSVs of SB3's logger, per car
    logs/eval/            TensorBoard scalars of the evaluations (x = total env steps)
    evals.csv             per turn: the trained car alone on the track for ``max_cycles``
                          steps from ``eval_races`` fixed starts: distance [m], off-track
                          fraction; its training episode return against the frozen cars
    learning_curve.png    those figures over training (with the MPC reference, if measured)
    final/car_K.zip       every car's last policy; best.zip the one that drives furthest
                          alone with under 5% off-track steps (else furthest)
    summary.json          the closing figures: steps, time, throughput, final evaluations
    MODEL_CARD.md         how best.zip was made and how it drives (the shipped checkpoint's card)

Every checkpoint is one zip (see :mod:`agents.ppo_agent`) holding the PPO model, the
VecNormalize statistics and this config. A killed run resumes from its latest checkpoint
(``alpha-racer selfplay --out DIR`` again, same settings): finished turns are kept and an
unfinished turn continues from its last in-turn checkpoint.
"""

from __future__ import annotations

import csv
import io
import json
import math
import shutil
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
from tqdm import tqdm

from experiments.infra.artifacts import claim, write_json, write_text
from experiments.learning.imitation import behaviour_cloning
from racing_env.files import atomic_path

SCHEMA_VERSION = 1
VEC_ENVS = ("batched", "dummy", "subproc")
WARMUP_OPPONENTS = ("raceline", "initial")
INITS = ("random", "bc")
RACELINE_GRIP = (0.75, 0.8, 0.85, 0.7, 0.9, 0.65, 0.95)
RACELINE_MU = RACELINE_GRIP  # the old name (mu names the heading in the state)
"""Friction of the raceline followers standing in for untrained cars, by opponent slot."""
OFFTRACK_BAR = 0.05


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

    def __post_init__(self):
        object.__setattr__(self, "net_arch", tuple(self.net_arch))
        for name in (
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
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1):
                raise ValueError(f"SelfPlayConfig.{name} must be a positive integer, got {v!r}")
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
        if not (isinstance(self.bc_log_std, (int, float)) and -5 <= self.bc_log_std <= 1):
            raise ValueError(
                f"SelfPlayConfig.bc_log_std must be in [-5, 1], got {self.bc_log_std!r}"
            )
        from racing_env.config import START_MODES

        if self.start not in START_MODES:
            raise ValueError(
                f"SelfPlayConfig.start must be one of {START_MODES}, got {self.start!r}"
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
        d = asdict(self)
        d["net_arch"] = list(self.net_arch)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> SelfPlayConfig:
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown SelfPlayConfig fields {sorted(unknown)}")
        return cls(**d)


# ---------------------------------------------------------------------- small file helpers
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


# ---------------------------------------------------------------------- envs and opponents
def race_config(cfg: SelfPlayConfig):
    from racing_env import RaceConfig, StartConfig

    return RaceConfig(
        n_cars=cfg.n_cars, max_cycles=cfg.max_cycles, start=StartConfig(mode=cfg.start)
    )


def make_learning_env(cfg: SelfPlayConfig, opponents: list, seed: int):
    """The learner's vectorised env (before VecMonitor / VecNormalize), seeded."""
    import copy

    if cfg.vec_env == "batched":
        from racing_env.vec_env import HeadToHeadVecEnv

        venv = HeadToHeadVecEnv(
            cfg.n_envs, opponents=opponents, track=cfg.track, config=race_config(cfg)
        )
    else:
        import gymnasium as gym
        from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

        import racing_env  # noqa: F401  registers the env
        from racing_env.registration import ENV_ID

        def make():
            opps = [copy.deepcopy(o) for o in opponents]
            return lambda: gym.make(
                ENV_ID,
                max_episode_steps=cfg.max_cycles,
                opponents=opps,
                track=cfg.track,
                config=race_config(cfg),
            )

        fns = [make() for _ in range(cfg.n_envs)]
        venv = (
            DummyVecEnv(fns) if cfg.vec_env == "dummy" else SubprocVecEnv(fns, start_method="fork")
        )
    venv.seed(seed)
    return venv


def frozen_policy(path):
    """The policy of a checkpoint as a batched agent (:class:`agents.ppo_agent.FrozenPolicy`)."""
    from agents.ppo_agent import PPOAgent

    return PPOAgent(checkpoint=path)


def live_policy(model, cfg: SelfPlayConfig):
    """The policy being trained, as a :class:`agents.ppo_agent.FrozenPolicy` with its current
    weights and observation statistics (what a checkpoint saved now would race)."""
    from agents.ppo_agent import FrozenPolicy

    return FrozenPolicy(
        model.policy,
        model.get_vec_normalize_env(),
        n_cars=cfg.n_cars,
        n_preview=race_config(cfg).n_preview,
    )


def _opponents(
    cfg: SelfPlayConfig, out: Path, state: SelfPlayState, car: int
) -> tuple[list, list[str]]:
    from racing_env.controllers import RacelineFollower

    opps, names = [], []
    for slot, k in enumerate(j for j in range(cfg.n_cars) if j != car):
        if state.trained_turns[k] == 0 and cfg.warmup_opponent == "raceline":
            grip = RACELINE_GRIP[slot % len(RACELINE_GRIP)]
            opps.append(RacelineFollower(grip=grip))
            names.append(f"raceline:grip={grip}")
        else:
            opps.append(frozen_policy(out / state.cars[k]))
            names.append(f"car_{k}@{state.trained_turns[k]}turns")
    return opps, names


# ---------------------------------------------------------------------- evaluation
def evaluate_solo(agent, cfg: SelfPlayConfig, races: int | None = None) -> dict:
    """The agent alone on the track for ``max_cycles`` steps from ``races`` fixed starts
    (seeds 0..races-1): mean distance [m] and fraction of steps off track."""
    from racing_env import RacingParallelEnv

    races = races or cfg.eval_races
    env = RacingParallelEnv(track=cfg.track, n_cars=1, max_cycles=cfg.max_cycles, start=cfg.start)
    dist, off = [], []
    for seed in range(races):
        obs, _ = env.reset(seed=seed)
        agent.reset(env.track, "car_0", seed)
        while env.agents:
            obs, *_ = env.step({"car_0": agent.act(obs["car_0"])})
        dist.append(float(env.core.progress()[0, 0]))
        off.append(float(env.core.offtracks[0, 0]) / cfg.max_cycles)
    return {
        "distance_m": float(np.mean(dist)),
        "off_track_frac": float(np.mean(off)),
        "distance_per_race": dist,
    }


def mpc_reference(cfg: SelfPlayConfig) -> dict:
    """The fixed-parameter MPC agent (``mpc``) alone, as :func:`evaluate_solo` measures."""
    from agents.mpc_agent import MPCAgent

    return evaluate_solo(MPCAgent(), cfg)


# ---------------------------------------------------------------------- SB3 callbacks
class _Clock:
    """Adds wall and CPU time since the last call to ``state`` (train_seconds, train_cpu_seconds)."""

    def __init__(self, state: SelfPlayState):
        self.state = state
        self.wall, self.cpu = time.perf_counter(), time.process_time()

    def book(self) -> None:
        wall, cpu = time.perf_counter(), time.process_time()
        self.state.train_seconds += wall - self.wall
        self.state.train_cpu_seconds += cpu - self.cpu
        self.wall, self.cpu = wall, cpu


def _callbacks(
    cfg, out: Path, state: SelfPlayState, turn: int, car: int, bar, turn_start_steps: int, clock
):
    from stable_baselines3.common.callbacks import BaseCallback

    class SelfPlayCheckpoint(BaseCallback):
        """Every ``checkpoint_every`` rollouts (after the policy update): checkpoint the
        learner with its VecNormalize and config, then record it in ``state.json``."""

        def _on_rollout_start(self) -> None:
            steps = self.model.num_timesteps - turn_start_steps
            if steps - state.turn_steps < cfg.checkpoint_every * cfg.rollout:
                return
            path = out / "checkpoints" / "partial" / f"turn_{turn:03d}_car_{car}_{steps:09d}.zip"
            _save(self.model, cfg, state, path, car, turn, steps)
            old = state.current
            _advance_state(state, steps)
            clock.book()
            state.current = str(path.relative_to(out))
            state.save(out / "state.json")
            if old and old != state.current:
                (out / old).unlink(missing_ok=True)  # superseded in-turn checkpoint

        def _on_rollout_end(self) -> None:
            buf = self.model.ep_info_buffer
            if buf:
                state.train_curve.append(
                    {
                        "turn": turn,
                        "car": car,
                        "total_steps": state.total_steps
                        + self.model.num_timesteps
                        - turn_start_steps
                        - state.turn_steps,
                        "ep_rew_mean": float(np.mean([e["r"] for e in buf])),
                    }
                )

        def _on_step(self) -> bool:
            bar.update(self.training_env.num_envs)
            return True

    return SelfPlayCheckpoint()


def _advance_state(state: SelfPlayState, turn_steps: int) -> None:
    """Count steps done in the current turn (``turn_steps`` in total so far)."""
    state.total_steps += turn_steps - state.turn_steps
    state.turn_steps = turn_steps


def _save(model, cfg, state, path: Path, car: int, turn: int, turn_steps: int, evaluation=None):
    from agents.ppo_agent import save_checkpoint

    meta = {
        "n_cars": cfg.n_cars,
        "n_preview": race_config(cfg).n_preview,
        "track": cfg.track,
        "car": car,
        "turn": turn,
        "cycle": turn // cfg.n_cars if turn >= 0 else -1,
        "turn_steps": turn_steps,
        "car_timesteps": int(model.num_timesteps),
        "trained_turns": state.trained_turns[car] if car >= 0 else 0,
        "selfplay_config": cfg.to_dict(),
        "race_config": race_config(cfg).to_dict(),
        "evaluation": evaluation,
        "saved": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    return save_checkpoint(model, model.get_vec_normalize_env(), path, meta)


# ---------------------------------------------------------------------- outputs
def write_evals_csv(out: Path, state: SelfPlayState) -> None:
    keys = [
        "phase",
        "turn",
        "cycle",
        "car",
        "total_steps",
        "train_seconds",
        "train_cpu_seconds",
        "distance_m",
        "off_track_frac",
        "train_ep_return_m",
        "distance_vs_mpc",
    ]
    buf = io.StringIO(newline="")
    w = csv.DictWriter(buf, keys, extrasaction="ignore")
    w.writeheader()
    w.writerows(state.evals)
    write_text(out / "evals.csv", buf.getvalue())


def plot_learning_curve(out: Path, state: SelfPlayState, cfg: SelfPlayConfig) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    ref = state.mpc_reference
    for car in range(cfg.n_cars):
        ev = [e for e in state.evals if e["car"] == car and e["phase"] == "ppo"]
        tc = [e for e in state.train_curve if e["car"] == car]
        if ev:
            x = [e["total_steps"] for e in ev]
            axes[0].plot(x, [e["distance_m"] for e in ev], "o-", label=f"car {car}")
            axes[1].plot(x, [100 * e["off_track_frac"] for e in ev], "o-", label=f"car {car}")
        if tc:
            axes[2].plot(
                [e["total_steps"] for e in tc],
                [e["ep_rew_mean"] for e in tc],
                ".-",
                lw=0.8,
                label=f"car {car} (learning)",
            )
    bc = [e for e in state.evals if e["phase"] == "bc"]
    if bc:
        axes[0].plot([0], [bc[-1]["distance_m"]], "k*", ms=10, label="behaviour-cloned start")
        axes[1].plot(
            [0], [100 * bc[-1]["off_track_frac"]], "k*", ms=10, label="behaviour-cloned start"
        )
    if ref:
        axes[0].axhline(ref["distance_m"], color="k", ls="--", lw=1, label="MPC alone")
        axes[0].axhline(0.8 * ref["distance_m"], color="k", ls=":", lw=1, label="80% of MPC")
    axes[1].axhline(100 * OFFTRACK_BAR, color="k", ls=":", lw=1, label="5%")
    axes[0].set_ylabel(f"distance alone in {cfg.max_cycles / 10:.0f} s [m]")
    axes[1].set_ylabel("off-track steps alone [%]")
    axes[2].set_ylabel("training episode return [m]\n(relative progress vs frozen cars)")
    axes[2].set_xlabel("total env steps (all cars)")
    for ax in axes:
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="best")
    axes[0].set_title(
        f"PPO self-play: {cfg.n_cars} cars, {cfg.cycles} cycles x "
        f"{cfg.steps_per_turn_actual} steps per turn"
    )
    fig.tight_layout()
    path = out / "learning_curve.png"
    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return path


# ---------------------------------------------------------------------- the pipeline
PPO_SETTINGS = (
    "learning_rate",
    "n_steps",
    "batch_size",
    "n_epochs",
    "gamma",
    "gae_lambda",
    "clip_range",
    "ent_coef",
)
"""The :class:`SelfPlayConfig` fields that are PPO's settings of the same names."""


def _new_model(cfg: SelfPlayConfig, env, seed: int):
    from stable_baselines3 import PPO

    return PPO(
        "MlpPolicy",
        env,
        **{name: getattr(cfg, name) for name in PPO_SETTINGS},
        policy_kwargs={"net_arch": list(cfg.net_arch)},
        seed=seed,
        device="cpu",
        verbose=0,
    )


def _behaviour_cloned_init(cfg: SelfPlayConfig, out: Path, state: SelfPlayState, bar) -> str:
    """``init="bc"``: one behaviour-cloned PPO model (:func:`~experiments.learning.imitation.behaviour_cloning`), the
    starting point of every car; saved as ``checkpoints/bc_init.zip`` and evaluated alone."""
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from racing_env.vec_env import HeadToHeadVecEnv

    venv = VecNormalize(
        VecMonitor(
            HeadToHeadVecEnv(
                cfg.n_envs,
                n_cars=cfg.n_cars,
                track=cfg.track,
                config=race_config(cfg),
                opponents=[_Idle()] * (cfg.n_cars - 1),
            )
        ),
        gamma=cfg.gamma,
        norm_reward=cfg.norm_reward,
    )
    model = _new_model(cfg, venv, cfg.seed)
    c0 = time.process_time()
    fit = behaviour_cloning(model, cfg, cfg.seed, race_config(cfg), RACELINE_GRIP)
    state.bc_cpu_seconds = round(time.process_time() - c0, 1)
    path = out / "checkpoints" / "bc_init.zip"
    ev = evaluate_solo(live_policy(model, cfg), cfg)
    _save(model, cfg, state, path, -1, -1, 0, {**ev, "bc": fit})
    state.evals = [e for e in state.evals if e["phase"] != "bc"]
    state.evals.append(_eval_row(cfg, state, -1, -1, ev, None, phase="bc"))
    bar.write(
        f"behaviour cloning (every car's start): {fit['samples']} samples, mse {fit['mse']:.4f}, "
        f"alone {ev['distance_m']:.1f} m, off track {100 * ev['off_track_frac']:.1f}%"
    )
    return str(path.relative_to(out))


class _Idle:
    """Placeholder opponent (the env built for the BC model only supplies its spaces)."""

    def reset(self, track, agent_id, seed=None):
        pass

    def act(self, observation):
        return np.zeros(2, np.float32)


def selfplay(
    cfg: SelfPlayConfig, out_dir, progress_bar: bool = True, max_turns: int | None = None
) -> dict:
    """Train (or resume) the self-play run in ``out_dir``; returns the summary.

    ``max_turns`` stops after that many turns in this call (the run stays resumable).
    """
    from racing_env.extras import require

    for module in ("torch", "stable_baselines3", "tensorboard"):
        require(module, "self-play training (alpha-racer selfplay)")
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import CSVOutputFormat, Logger, make_output_format
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from agents.ppo_agent import load_vecnormalize

    torch.set_num_threads(1)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for sub in ("checkpoints/partial", "logs", "final"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    claim(
        out / "config.json",
        {"schema_version": SCHEMA_VERSION, "config": cfg.to_dict()},
        "a self-play run",
    )
    state_path = out / "state.json"
    state = SelfPlayState.load(state_path, cfg)
    if cfg.mpc_reference and state.mpc_reference is None:
        state.mpc_reference = mpc_reference(cfg)
        state.save(state_path)
    eval_logger = Logger(
        str(out / "logs" / "eval"), [make_output_format("tensorboard", str(out / "logs" / "eval"))]
    )

    total = cfg.turns * cfg.steps_per_turn_actual
    bar = tqdm(
        total=total,
        initial=state.total_steps,
        unit="step",
        desc="selfplay",
        disable=not progress_bar,
        smoothing=0.05,
        dynamic_ncols=True,
    )
    turns_run = 0
    while state.turn < cfg.turns and (max_turns is None or turns_run < max_turns):
        turn = state.turn
        car = turn % cfg.n_cars
        opponents, names = _opponents(cfg, out, state, car)
        seed = int(
            np.random.SeedSequence([cfg.seed, turn, state.turn_steps]).generate_state(1)[0] % 2**31
        )
        venv = VecMonitor(make_learning_env(cfg, opponents, seed))
        resume_from = state.current or state.cars[car]
        if not resume_from and cfg.init == "bc":
            if not state.bc_init:
                state.bc_init = _behaviour_cloned_init(cfg, out, state, bar)
                state.save(state_path)
            resume_from = state.bc_init
        if resume_from:
            model = PPO.load(out / resume_from, env=None, device="cpu")
            vecnorm = load_vecnormalize(out / resume_from)
            vecnorm.set_venv(venv)
            vecnorm.training = True
            model.set_env(vecnorm)
        else:
            vecnorm = VecNormalize(venv, gamma=cfg.gamma, norm_reward=cfg.norm_reward)
            model = _new_model(cfg, vecnorm, cfg.seed + car)
        model.set_random_seed(seed)  # seeds the venv too
        model.ep_info_buffer = None  # episode stats of this turn only
        log_dir = out / "logs" / f"car_{car}"
        log_dir.mkdir(parents=True, exist_ok=True)
        model.set_logger(
            Logger(
                str(log_dir),
                [
                    make_output_format("tensorboard", str(log_dir)),
                    CSVOutputFormat(
                        str(log_dir / f"progress_turn{turn:03d}_{state.turn_steps:09d}.csv")
                    ),
                ],
            )
        )
        turn_start = model.num_timesteps - state.turn_steps
        bar.set_postfix_str(f"turn {turn + 1}/{cfg.turns} car {car} vs {', '.join(names)}")
        clock = _Clock(state)
        callback = _callbacks(cfg, out, state, turn, car, bar, turn_start, clock)
        remaining = cfg.steps_per_turn_actual - state.turn_steps
        if remaining > 0:
            model.learn(total_timesteps=remaining, reset_num_timesteps=False, callback=callback)
        clock.book()
        venv.close()
        # turn end: checkpoint, evaluation, state, outputs
        _advance_state(state, model.num_timesteps - turn_start)
        state.trained_turns[car] += 1
        path = out / "checkpoints" / f"turn_{turn:03d}_car_{car}.zip"
        evaluation = evaluate_solo(live_policy(model, cfg), cfg)
        _save(model, cfg, state, path, car, turn, state.turn_steps, evaluation)
        ep = [e["ep_rew_mean"] for e in state.train_curve if e["turn"] == turn]
        ref = state.mpc_reference
        row = _eval_row(cfg, state, turn, car, evaluation, ep[-1] if ep else None)
        state.evals.append(row)
        old_current = state.current
        state.cars[car] = str(path.relative_to(out))
        state.current = None
        state.turn += 1
        state.turn_steps = 0
        state.save(state_path)
        if old_current and (out / old_current).exists() and old_current != state.cars[car]:
            (out / old_current).unlink()
        for key in ("distance_m", "off_track_frac", "distance_vs_mpc", "train_ep_return_m"):
            if row[key] is not None:
                eval_logger.record(f"eval_car_{car}/{key}", row[key])
        eval_logger.dump(step=state.total_steps)
        write_evals_csv(out, state)
        plot_learning_curve(out, state, cfg)
        bar.write(
            f"turn {turn + 1}/{cfg.turns} car {car}: {state.total_steps} steps, "
            f"alone {row['distance_m']:.1f} m"
            + (f" ({100 * row['distance_vs_mpc']:.0f}% of MPC)" if ref else "")
            + f", off track {100 * row['off_track_frac']:.1f}%"
            + (f", training return {row['train_ep_return_m']:.2f} m" if ep else "")
        )
        turns_run += 1
    bar.close()
    eval_logger.close()
    return finish(cfg, out, state)


def _eval_row(cfg, state, turn, car, evaluation, ep_return, phase="ppo") -> dict:
    ref = state.mpc_reference
    return {
        "phase": phase,
        "turn": turn,
        "cycle": turn // cfg.n_cars if turn >= 0 else -1,
        "car": car,
        "total_steps": state.total_steps,
        "train_seconds": round(state.train_seconds, 1),
        "train_cpu_seconds": round(state.train_cpu_seconds, 1),
        "distance_m": round(evaluation["distance_m"], 3),
        "off_track_frac": round(evaluation["off_track_frac"], 4),
        "train_ep_return_m": None if ep_return is None else round(ep_return, 3),
        "distance_vs_mpc": round(evaluation["distance_m"] / ref["distance_m"], 4) if ref else None,
    }


CLI_FLAGS = {
    "n_cars": "--cars",
    "cycles": "--cycles",
    "steps_per_turn": "--steps-per-turn",
    "n_envs": "--envs",
    "batch_size": "--batch-size",
    "n_epochs": "--epochs",
    "learning_rate": "--lr",
    "gamma": "--gamma",
    "n_steps": "--n-steps",
    "track": "--track",
    "max_cycles": "--race-steps",
    "seed": "--seed",
    "vec_env": "--vec-env",
    "warmup_opponent": "--warmup-opponent",
    "checkpoint_every": "--checkpoint-every",
    "eval_races": "--eval-races",
    "init": "--init",
    "bc_steps": "--bc-steps",
}


def command_line(cfg: SelfPlayConfig, out: str) -> str:
    """The ``alpha-racer selfplay`` command that trains ``cfg`` (fields off their default)."""
    default = SelfPlayConfig()
    parts = ["alpha-racer", "selfplay", "--out", str(out)]
    for f in fields(cfg):
        v = getattr(cfg, f.name)
        if v == getattr(default, f.name):
            continue
        if f.name == "mpc_reference":
            parts.append("--no-mpc-reference")
        elif f.name in CLI_FLAGS:
            parts += [CLI_FLAGS[f.name], str(v)]
        else:
            parts.append(f"(SelfPlayConfig.{f.name}={v!r})")
    return " ".join(parts)


def model_card(cfg: SelfPlayConfig, summary: dict, state: SelfPlayState) -> str:
    """Markdown description of the run's ``best.zip``: command, schedule, time, figures."""
    b, ref = summary["best"], summary["mpc_reference"]
    lines = [
        f"# PPO self-play checkpoint (car {b['car']} of a {cfg.n_cars}-car run)",
        "",
        "Trained by",
        "",
        "```bash",
        command_line(cfg, "runs/ppo_default")
        + ("" if summary["done"] else f" --max-turns {summary['turns']}"),
        "```",
        "",
        "(then `best.zip` of that folder is this checkpoint; `--max-turns` stops the run after "
        "that many turns, so the schedule below was cut short there)"
        if not summary["done"]
        else "(`best.zip` of that folder is this checkpoint)",
        "",
        f"* schedule: {cfg.n_cars} cars x {cfg.cycles} cycles x {cfg.steps_per_turn_actual} "
        f"env steps per turn ({cfg.steps_per_turn} rounded up to whole rollouts of "
        f"{cfg.n_steps} x {cfg.n_envs}); the paper's is 33 cycles x 100k"
        + (" (this is a reduced schedule)" if cfg.cycles < 33 else ""),
        f"* PPO: batch {cfg.batch_size}, {cfg.n_epochs} epochs, lr {cfg.learning_rate}, "
        f"gamma {cfg.gamma}, {cfg.n_envs} parallel races, net {list(cfg.net_arch)}; "
        f"start: {cfg.init}"
        + (
            " (behaviour cloning of the raceline follower, "
            f"{cfg.bc_rounds} DAgger rounds of {cfg.bc_steps} steps)"
            if cfg.init == "bc"
            else ""
        ),
        f"* {summary['turns']}/{cfg.turns} turns, {summary['total_steps']} PPO env steps, "
        f"{summary['train_seconds']:.0f} s of training wall time ({summary['steps_per_s']} "
        f"steps/s), {summary['train_cpu_seconds']:.0f} CPU s ({summary['steps_per_cpu_s']} steps per CPU s)"
        + (
            f"; behaviour cloning {summary['bc_cpu_seconds']:.0f} CPU s"
            if summary.get("bc_cpu_seconds")
            else ""
        ),
        "",
        f"Alone on `{cfg.track}` for {cfg.max_cycles / 10:.0f} s ({cfg.eval_races} fixed starts):",
        "",
    ]
    if ref:
        lines.append(
            f"* fixed-parameter MPC (`mpc`): {ref['distance_m']:.1f} m, "
            f"off track {100 * ref['off_track_frac']:.1f}% of steps"
        )
    lines += [
        f"* this checkpoint: {b['distance_m']:.1f} m"
        + (f" ({100 * b['distance_vs_mpc']:.0f}% of the MPC)" if b.get("distance_vs_mpc") else "")
        + f", off track {100 * b['off_track_frac']:.1f}% of steps",
        "",
        "Over training (each car after each of its turns; `bc` = the shared start):",
        "",
        "| phase | turn | car | total steps | distance m | vs MPC | off track % | training return m |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for e in state.evals:
        vs = f"{100 * e['distance_vs_mpc']:.0f}%" if e.get("distance_vs_mpc") else "-"
        tr = "-" if e.get("train_ep_return_m") is None else f"{e['train_ep_return_m']:.1f}"
        lines.append(
            f"| {e['phase']} | {e['turn'] + 1 if e['turn'] >= 0 else '-'} | "
            f"{e['car'] if e['car'] >= 0 else 'all'} | {e['total_steps']} | "
            f"{e['distance_m']:.1f} | {vs} | {100 * e['off_track_frac']:.1f} | {tr} |"
        )
    return "\n".join(lines) + "\n"


def summarize(cfg: SelfPlayConfig, state: SelfPlayState, out) -> dict:
    """The closing figures of a run's state (no files touched); ``best`` is the last policy of
    the car that drives furthest alone with under 5% off-track steps (else furthest)."""
    last = {}
    for e in state.evals:
        if e["phase"] == "ppo":
            last[e["car"]] = e
    best = None
    if last:
        ok = [e for e in last.values() if e["off_track_frac"] < OFFTRACK_BAR] or list(last.values())
        best = max(ok, key=lambda e: e["distance_m"])
    wall, cpu = state.train_seconds, state.train_cpu_seconds
    return {
        "done": state.turn >= cfg.turns,
        "turns": state.turn,
        "total_steps": state.total_steps,
        "train_seconds": round(wall, 1),
        "steps_per_s": round(state.total_steps / wall, 1) if wall else None,
        "train_cpu_seconds": round(cpu, 1),
        "steps_per_cpu_s": round(state.total_steps / cpu, 1) if cpu else None,
        "bc_cpu_seconds": state.bc_cpu_seconds,
        "mpc_reference": state.mpc_reference,
        "final": last,
        "best": None if best is None else {"path": state.cars[best["car"]], **best},
        "out": str(out),
    }


def finish(cfg: SelfPlayConfig, out: Path, state: SelfPlayState) -> dict:
    """Copy the final policies, write ``best.zip``, ``summary.json`` and ``MODEL_CARD.md``
    (also for a partial run)."""
    summary = summarize(cfg, state, out)
    for car, path in enumerate(state.cars):
        if path:
            shutil.copyfile(out / path, out / "final" / f"car_{car}.zip")
    if summary["best"] is not None:
        shutil.copyfile(out / summary["best"]["path"], out / "best.zip")
    state.done = summary["done"]
    state.save(out / "state.json")
    write_json(out / "summary.json", summary)
    if summary["best"] is not None:
        write_text(out / "MODEL_CARD.md", model_card(cfg, summary, state))
    return summary
