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

Vehicle class (``vehicle_class``, ``wake``): the paper's 1:43 ``"orca"`` cars by default;
``"fullsize"`` trains full-size single-seaters on a full-scale circuit (``tumftm:Monza``
unless ``track`` names another) with the wake (strength 1 unless ``wake`` says otherwise).
Every race of the run is of that class and wake: the learning env, behaviour cloning, the
solo evaluations and the MPC reference; the raceline followers and the MPC take the class
from the track. The checkpoints record both, and the ``ppo`` agent races a checkpoint on
tracks of its class only.

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

import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from experiments.infra.artifacts import claim
from experiments.learning.config import RACELINE_GRIP, SelfPlayConfig, SelfPlayState, race_config
from experiments.learning.envs import (
    evaluate_solo,
    live_policy,
    make_learning_env,
    make_opponents,
    mpc_reference,
)
from experiments.learning.imitation import behaviour_cloning
from experiments.learning.report import eval_row, finish, plot_learning_curve, write_evals_csv

SCHEMA_VERSION = 1


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
        "vehicle_class": cfg.vehicle_class,  # the ppo agent races it on tracks of this class only
        "wake": cfg.wake,
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
    state.evals.append(eval_row(cfg, state, -1, -1, ev, None, phase="bc"))
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
        opponents, names = make_opponents(cfg, out, state, car)
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
        row = eval_row(cfg, state, turn, car, evaluation, ep[-1] if ep else None)
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
