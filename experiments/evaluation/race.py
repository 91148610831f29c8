"""Run one race between agents and summarise it (the ``alpha-racer race`` command)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from agents import check_field_size, make_agent_spec
from agents.theta import policy_space
from experiments.evaluation.metrics import race_metrics
from experiments.infra.artifacts import write_json
from racing_env import RacingParallelEnv
from racing_env.config import RulesConfig
from racing_env.gym_env import act_named


@dataclass
class RaceResult:
    """What happened in a race. ``states`` (T + 1, N, 6) holds every car's Frenet state."""

    agents: list[str]
    track: str  # track spec, as given to make_track
    seed: int
    dt: float
    states: np.ndarray
    progress: np.ndarray  # (N,) final unwrapped s minus the race's start line [m]
    lap_times: list[list[float]]  # per car, s per completed lap
    contacts: np.ndarray  # (N,) steps with contact
    off_tracks: np.ndarray  # (N,) steps off track
    decision_ms: np.ndarray  # (N,) mean wall time per act() [ms]
    env_step_ms: float  # mean env.step wall time [ms]
    agent_stats: list[dict] = field(default_factory=list)
    contact_dn: float = RulesConfig().contact_dn  # [m] the race's lateral contact box
    #: per car, the theta it drove at every step, (T, D) in its policy space's order
    #: (``theta_names``), or None for an agent without a theta (IBR, PPO, raceline)
    thetas: list = field(default_factory=list)
    theta_names: list = field(default_factory=list)
    vehicle_class: str = "orca"  # the class the race was run in
    wake: float = 0.0  # the wake's strength

    @property
    def metrics(self) -> dict:
        """Strategy metrics of the race (:func:`experiments.evaluation.metrics.race_metrics`): passes
        per car, passes through contact, wins from behind, time within 1 m behind."""
        return race_metrics(self.states, self.dt, self.contact_dn)

    @property
    def order(self) -> np.ndarray:
        """Car indices from winner to last, by total progress along the track (unwrapped s)."""
        return np.argsort(-self.progress, kind="stable")

    def table(self) -> str:
        """Human-readable result table."""
        lead = self.progress.max()
        speed = lead / max(len(self.states) - 1, 1) / self.dt
        m = self.metrics
        rows = [
            f"Race on '{self.track}' (seed {self.seed}), {len(self.states) - 1} steps "
            f"= {(len(self.states) - 1) * self.dt:.1f} s",
            f"{'pos':>3}  {'car':<6} {'agent':<18} {'progress m':>10} {'gap m':>7} {'gap s':>6} "
            f"{'laps':>4} {'best lap s':>10} {'contacts':>8} {'off-track':>9} {'fallbacks':>9} "
            f"{'ms/decision':>11} {'passes':>6} {'via contact':>11} {'<1m behind s':>12}",
        ]
        for pos, i in enumerate(self.order, 1):
            laps = self.lap_times[i]
            lap_durations = np.diff([0.0] + laps)
            best = f"{lap_durations[1:].min():.2f}" if len(laps) > 1 else "-"
            gap = lead - self.progress[i]
            fb = self.agent_stats[i].get("fallbacks", "-") if self.agent_stats else "-"
            rows.append(
                f"{pos:>3}  car_{i:<2} {self.agents[i]:<18} {self.progress[i]:>10.2f} "
                f"{gap:>7.2f} {gap / max(speed, 1e-9):>6.2f} {len(laps):>4} {best:>10} "
                f"{self.contacts[i]:>8} {self.off_tracks[i]:>9} {fb:>9} {self.decision_ms[i]:>11.3f} "
                f"{m['passes'][i]:>6} {m['passes_contact'][i]:>11} {m['behind_1m_s'][i]:>12.1f}"
            )
        rows.append(
            f"winner car_{m['winner']} started "
            + ("from behind" if m["won_from_behind"] else "at the front")
            + f" (front: car_{m['front']}); passes (held >= 1 s, body clear sideways): "
            + (
                ", ".join(
                    f"car_{e['passer']} past car_{e['passed']} at {e['time_s']:.1f} s"
                    + (" (through contact)" if e["kind"] == "contact" else "")
                    for e in m["pass_events"]
                    if e["kind"] in ("pass", "contact")
                )
                or "none"
            )
        )
        rows.append(f"env step: {self.env_step_ms:.3f} ms mean")
        return "\n".join(rows)

    def summary(self) -> dict:
        return {
            "agents": self.agents,
            "track": self.track,
            "seed": self.seed,
            "steps": len(self.states) - 1,
            "order": [f"car_{i}" for i in self.order],
            "progress_m": self.progress.round(4).tolist(),
            "lap_times_s": self.lap_times,
            "contacts": self.contacts.tolist(),
            "off_tracks": self.off_tracks.tolist(),
            "decision_ms": self.decision_ms.round(4).tolist(),
            "env_step_ms": round(self.env_step_ms, 4),
            "agent_stats": self.agent_stats,
            "metrics": self.metrics,
        } | (
            {}
            if (self.vehicle_class, self.wake) == ("orca", 0.0)
            else {
                "vehicle_class": self.vehicle_class,
                "wake": self.wake,
            }
        )


def start_order(regions, n_cars: int, start: str = "regions") -> list[int] | None:
    """``run_race``'s ``order`` from region names, one per car (``["R2", "R1", "R3"]``: car 0
    starts in R2, ...; R1 is the front-most), or None for ``regions=None`` (an order drawn
    from the seed). ``ValueError`` naming the value unless the names are a permutation of
    R1..R<n_cars> and ``start`` is ``"regions"``."""
    if regions is None:
        return None
    regions = list(regions)
    if start != "regions":
        raise ValueError(f"start regions {regions} need start='regions', got start={start!r}")
    names = [f"R{k + 1}" for k in range(n_cars)]
    if sorted(regions, key=str) != sorted(names):
        raise ValueError(
            f"start regions must name each of {' '.join(names)} once, one per car "
            f"({n_cars} cars), got {' '.join(map(str, regions))}"
        )
    return [names.index(r) for r in regions]


def agent_seed(seed: int, k: int) -> int:
    """The seed of car k's agent in race ``seed`` (:func:`start_race`'s reset)."""
    return seed + 1000 * (k + 1)


def start_race(env: RacingParallelEnv, agents: list, seed: int, order=None) -> dict:
    """Reset ``env`` to the start of race ``seed`` (``order`` as :func:`run_race`'s) and
    every agent on its track, car k's agent with seed ``seed + 1000 (k + 1)``; returns the
    first observations. Every race that must be :func:`run_race`'s race bit for bit starts
    here."""
    obs, _ = env.reset(seed=seed, options=None if order is None else {"order": list(order)})
    for k, (a, agent_id) in enumerate(zip(agents, env.possible_agents)):
        a.reset(env.track, agent_id, agent_seed(seed, k))
    return obs


def run_race(
    agent_names: list[str],
    track: str = "default",
    seed: int = 0,
    max_cycles: int = 500,
    start: str = "regions",
    laps: int | None = None,
    render: bool = False,
    progress_bar: bool = True,
    order=None,
    vehicle_class: str | None = None,
    wake: float | None = None,
    follow: int | None = None,
):
    """Race ``agent_names`` (agent specs, one per car: a registry name with optional
    parameters, ``"raceline:grip=0.75"``) and return ``(RaceResult, frames)``.

    ``order`` (start ``"regions"``): ``order[i]`` is car i's start region (0 = R1, the
    front-most); default a random permutation drawn from ``seed``. ``frames`` is a list of
    RGB arrays when ``render`` is true, else empty. ``vehicle_class`` and ``wake``: the env's
    (:class:`~racing_env.RacingParallelEnv`; default the paper's 1:43 class without a wake);
    a track name is built at the class's scale and the agents learn the class from it.
    ``follow``: the car a followed view (full size) is centred on, default the lead car.
    """
    if not agent_names:
        raise ValueError("a race needs at least one agent")
    env = RacingParallelEnv(
        track=track,
        n_cars=len(agent_names),
        max_cycles=max_cycles,
        laps=laps,
        start=start,
        vehicle_class=vehicle_class,
        wake=wake,
    )
    agents = [make_agent_spec(spec) for spec in agent_names]
    for agent, spec, agent_id in zip(agents, agent_names, env.possible_agents):
        check_field_size(agent, len(agents), agent_id, spec)
    obs = start_race(env, agents, seed, order)
    n = len(agents)
    states = [env.core.state[0].copy()]
    frames = [env.render_frame(follow)] if render else []
    decide = np.zeros(n)
    thetas = [[] if hasattr(a, "driven_theta") else None for a in agents]
    env_time = 0.0
    steps = 0
    with tqdm(
        total=max_cycles, desc="race", unit="step", delay=3.0, disable=not progress_bar
    ) as bar:
        while env.agents:
            actions = {}
            for k, agent_id in enumerate(env.possible_agents):
                t0 = time.perf_counter()
                actions[agent_id] = act_named(agents[k], obs[agent_id], agent_id, agent_names[k])
                decide[k] += time.perf_counter() - t0
                if thetas[k] is not None:
                    thetas[k].append(agents[k].driven_theta.as_array(agents[k].space))
            t0 = time.perf_counter()
            obs, _, _, _, _ = env.step(actions)
            env_time += time.perf_counter() - t0
            steps += 1
            states.append(env.core.state[0].copy())
            if render:
                frames.append(env.render_frame(follow))
            bar.update(1)
    core = env.core
    result = RaceResult(
        agents=list(agent_names),
        track=track if isinstance(track, str) else env.track.name,
        seed=seed,
        dt=env.config.dt,  # noqa: E501
        states=np.array(states),
        progress=core.state[0, :, 0] - core.s_line[0],
        lap_times=[list(t) for t in core.lap_times[0]],
        contacts=core.contacts[0].copy(),
        off_tracks=core.offtracks[0].copy(),
        decision_ms=1e3 * decide / max(steps, 1),
        env_step_ms=1e3 * env_time / max(steps, 1),
        agent_stats=[dict(getattr(a, "stats", {}) or {}) for a in agents],
        contact_dn=env.config.rules.contact_dn,
        thetas=[None if t is None else np.array(t).reshape(steps, -1) for t in thetas],
        theta_names=[
            list(policy_space(a.space).names) if t is not None else None
            for a, t in zip(agents, thetas)
        ],
        vehicle_class=env.config.vehicle_class,
        wake=float(env.config.wake),
    )
    env.close()
    return result, frames


def write_outputs(result: RaceResult, frames: list, out: Path, animation: str = "gif") -> dict:
    """Write ``result.json``, ``trajectories.png`` and the animation into ``out``; returns paths."""
    from racing_env.raceline import get_raceline
    from racing_env.render import plot_trajectories, save_animation
    from racing_env.tracks import make_track

    out.mkdir(parents=True, exist_ok=True)
    paths = {"summary": out / "result.json", "trajectories": out / "trajectories.png"}
    from experiments.evaluation.theta_plot import plot_thetas, varying_cars

    if varying_cars(result.thetas):  # a car that chose its theta during the race
        paths["thetas"] = out / "thetas.png"
        plot_thetas(result, paths["thetas"])
    write_json(paths["summary"], result.summary())
    track = make_track(result.track, vehicle_class=result.vehicle_class)
    rl = get_raceline(track)
    plot_trajectories(
        track,
        result.states,
        paths["trajectories"],
        raceline_xy=(rl.x, rl.y),
        labels=[f"car_{i} ({a})" for i, a in enumerate(result.agents)],
    )
    if frames:
        paths["animation"] = out / f"race.{animation}"
        save_animation(frames, paths["animation"], fps=int(round(1.0 / result.dt)))
    return paths


def check_animation_format(animation: str) -> None:
    """Raise a ``ValueError`` before a race if its animation could not be written: an unknown
    format, or ``mp4`` without ffmpeg."""
    from racing_env.render import ffmpeg_available

    if animation not in ("gif", "mp4"):
        raise ValueError(f"unknown animation format {animation!r}; expected gif or mp4")
    if animation == "mp4" and not ffmpeg_available():
        raise ValueError(
            "--format mp4 needs ffmpeg, which is missing (not on PATH, and "
            "imageio-ffmpeg is not installed); install ffmpeg or use --format gif"
        )
