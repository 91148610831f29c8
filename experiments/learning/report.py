"""What a self-play run leaves behind: ``evals.csv``, the learning curve, ``summary.json``,
``final/``, ``best.zip`` and the model card (:func:`finish`)."""

from __future__ import annotations

import csv
import io
import shutil
from dataclasses import fields
from pathlib import Path

from experiments.infra.artifacts import write_json, write_text
from experiments.learning.config import OFFTRACK_BAR, SelfPlayConfig, SelfPlayState
from racing_env.files import atomic_path


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


def eval_row(cfg, state, turn, car, evaluation, ep_return, phase="ppo") -> dict:
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
    "wake": "--wake",
}


def command_line(cfg: SelfPlayConfig, out: str) -> str:
    """The ``alpha-racer selfplay`` command that trains ``cfg`` (fields off their default)."""
    default = SelfPlayConfig(vehicle_class=cfg.vehicle_class)  # the class's track and wake
    parts = ["alpha-racer", "selfplay", "--out", str(out)]
    if cfg.vehicle_class != SelfPlayConfig.vehicle_class:
        parts += ["--vehicle-class", cfg.vehicle_class]
    for f in fields(cfg):
        v = getattr(cfg, f.name)
        if f.name == "vehicle_class" or v == getattr(default, f.name):
            continue
        if f.name == "mpc_reference":
            parts.append("--no-mpc-reference")
        elif f.name in CLI_FLAGS:
            parts += [CLI_FLAGS[f.name], str(v)]
        else:
            parts.append(f"(SelfPlayConfig.{f.name}={v!r})")
    return " ".join(parts)


def model_card(
    cfg: SelfPlayConfig, summary: dict, state: SelfPlayState, out: str = "runs/ppo_default"
) -> str:
    """Markdown description of the run's ``best.zip``: command (with ``--out out``), schedule,
    time, figures."""
    b, ref = summary["best"], summary["mpc_reference"]
    lines = [
        f"# PPO self-play checkpoint (car {b['car']} of a {cfg.n_cars}-car run)",
        "",
        "Trained by",
        "",
        "```bash",
        command_line(cfg, str(out))
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
        f"Alone on `{cfg.track}`"
        + (
            f" ({cfg.vehicle_class} class, wake {cfg.wake:g})"
            if (cfg.vehicle_class, cfg.wake) != ("orca", 0.0)
            else ""
        )
        + f" for {cfg.max_cycles / 10:.0f} s ({cfg.eval_races} fixed starts):",
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
        write_text(out / "MODEL_CARD.md", model_card(cfg, summary, state, out))
    return summary
