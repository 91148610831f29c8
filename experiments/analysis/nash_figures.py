"""The figures of the Nash analyses (:mod:`experiments.analysis.nash`): the approximation gap's
histograms, the regret, the potential slices (the paper's Figure 3), the track, and an
overtake from a benchmark as an animation."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np

DT = 0.1  # control period of the races [s]


def _histograms(ax, bins, *layers) -> None:
    """Overlaid histograms on ``bins``, drawn in order. Each layer is ``(values, colour, alpha,
    label)``: filled with that alpha, or a step outline (line width 1.2) where alpha is None."""
    for values, colour, alpha, label in layers:
        if alpha is None:
            ax.hist(values, bins=bins, histtype="step", color=colour, lw=1.2, label=label)
        else:
            ax.hist(values, bins=bins, color=colour, alpha=alpha, label=label)


def plot_gap(gap: dict, path: Path) -> None:
    fig, ax = _figure((6, 4))
    rel = 100 * np.asarray(gap["rel"])
    const = 100 * np.asarray(gap["const_rel"])
    hi = max(20.0, float(np.percentile(const, 99)))
    bins = np.linspace(0, hi, 41)
    _histograms(
        ax,
        bins,
        (
            np.clip(const, 0, hi),
            "0.5",
            None,
            f"constant potential (median {100 * gap['const_median']:.1f}%)",
        ),
        (
            np.clip(rel, 0, hi),
            "tab:blue",
            0.8,
            f"learned Phi (median {100 * gap['median']:.1f}%, 95th {100 * gap['p95']:.1f}%)",
        ),
    )
    ax.axvline(100 * gap["median"], color="k", ls="--", lw=1)
    ax.set_xlabel("|dPhi - dV_i| / range(V)  [%]")
    ax.set_ylabel("unilateral deviations")
    ax.set_title(
        f"Approximation gap on {gap['races']} held-out races "
        f"({100 * gap['within_10pct']:.1f}% within 10%)"
    )
    ax.legend(fontsize=8)
    _save(fig, path)


def plot_regret(reg: dict, path: Path) -> None:
    fig, ax = _figure((6, 4))
    a = 100 * np.asarray(reg["regret_rel"])
    v = 100 * np.asarray(reg["value_regret_rel"])
    hi = max(5.0, float(max(a.max(), v.max())) * 1.05)
    bins = np.linspace(0, hi, 31)
    _histograms(
        ax,
        bins,
        (
            a,
            "tab:orange",
            0.85,
            f"simulated (median {100 * reg['regret_median']:.2f}%, max "
            f"{100 * reg['regret_max']:.2f}%)",
        ),
        (v, "k", None, f"learned V (median {100 * reg['value_regret_median']:.2f}%)"),
    )
    ax.axvline(3.0, color="0.4", ls=":", lw=1, label="paper: within 3%")
    ax.set_xlabel("Nash regret / range(V)  [%]")
    ax.set_ylabel("(state, car) pairs")
    ax.set_title(f"Nash regret at theta*: {reg['states']} race states x {reg['cars']} cars")
    ax.legend(fontsize=8)
    _save(fig, path)


def plot_slices(track, state, sl: dict, path: Path) -> None:
    from matplotlib import cm

    names = list(sl["params"])  # the model's policy space's parameters
    fig, axes = _figure((4 * len(names), 7.5), rows=2, cols=len(names))
    ego = sl["ego"]
    (xl, yl), (xr, yr) = track.edges()
    xs, ys = track.to_cartesian(state[:, 0], state[:, 1])
    for p, name in enumerate(names):
        d = sl["params"][name]
        ax = axes[0][p]
        ax.plot(d["grid"], d["phi"], color="tab:blue", label="Phi")
        i_star = d["theta_star"]
        phi_star = np.interp(i_star, d["grid"], d["phi"])
        ax.plot(
            [i_star],
            [phi_star],
            marker="D",
            color="gold",
            mec="k",
            ms=9,
            ls="",
            label="maximiser theta*",
        )
        ax.set_xlabel(f"ego {name}")
        if p == 0:
            ax.set_ylabel("potential Phi(x, theta)")
            ax.legend(fontsize=8)
        ax.set_title(f"Phi along {name}")
        ax2 = axes[1][p]
        ax2.plot(xl, yl, color="0.3", lw=0.8)
        ax2.plot(xr, yr, color="0.3", lw=0.8)
        vals = np.asarray(d["rollout_values"][:-1])
        norm = (vals - min(d["grid"])) / max(max(d["grid"]) - min(d["grid"]), 1e-9)
        all_x, all_y = [], []
        for (tx, ty), c, val, prog in zip(
            d["trajectories"][:-1], norm, vals, d["rollout_progress_m"]
        ):
            ax2.plot(tx, ty, color=cm.viridis(c), lw=1.2, label=f"{name}={val:.2f}: {prog:.2f} m")
            all_x += tx
            all_y += ty
        tx, ty = d["trajectories"][-1]
        ax2.plot(
            tx,
            ty,
            color="gold",
            lw=2.5,
            ls="--",
            label=f"theta*: {d['rollout_progress_m'][-1]:.2f} m",
        )
        for i in range(len(state)):
            ax2.plot(xs[i], ys[i], "o", color="r" if i == ego else "k", ms=5)
        pad = 0.6
        ax2.set_xlim(min(all_x + tx) - pad, max(all_x + tx) + pad)
        ax2.set_ylim(min(all_y + ty) - pad, max(all_y + ty) + pad)
        ax2.set_aspect("equal")
        ax2.legend(fontsize=6, loc="best")
        ax2.set_title(f"ego path over {DT * (len(tx) - 1):.0f} s (progress)", fontsize=9)
    fig.suptitle(
        f"Potential against each of the ego's parameters (car_{ego}, others at theta*); "
        f"gold: the maximiser"
    )
    _save(fig, path)


def plot_track(track, path: Path) -> None:
    """Edges, racing line coloured by speed, and the start regions R1-R3 (default StartConfig)."""
    from matplotlib.collections import LineCollection

    from racing_env.config import StartConfig
    from racing_env.raceline import get_raceline

    rl = get_raceline(track)
    sc = StartConfig()
    fig, ax = _figure((8, 6))
    (xl, yl), (xr, yr) = track.edges()
    close = lambda a: np.append(a, a[0])
    ax.plot(close(xl), close(yl), color="0.2", lw=1)
    ax.plot(close(xr), close(yr), color="0.2", lw=1)
    pts = np.column_stack([close(rl.x), close(rl.y)])
    lc = LineCollection(np.stack([pts[:-1], pts[1:]], axis=1), cmap="viridis", linewidths=2)
    lc.set_array(0.5 * (rl.vx + np.roll(rl.vx, -1)))
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, label="racing-line speed [m/s]")
    for r in range(3):
        front = sc.s0 - r * (sc.region_length + sc.region_gap)
        s = np.linspace(front - sc.region_length, front, 20)
        (ax_, ay_), (bx_, by_) = track.edges(s)
        poly = np.concatenate([np.column_stack([ax_, ay_]), np.column_stack([bx_, by_])[::-1]])
        ax.fill(poly[:, 0], poly[:, 1], color=("tab:red", "tab:orange", "tab:green")[r], alpha=0.5)
        cx, cy = track.to_cartesian(np.array([front - sc.region_length / 2]), np.array([0.0]))
        ax.annotate(
            f"R{r + 1}",
            (float(np.ravel(cx)[0]), float(np.ravel(cy)[0])),
            xytext=(0, 14),
            textcoords="offset points",
            ha="center",
            fontsize=10,
            fontweight="bold",
        )
    ax.set_aspect("equal")
    ax.set_title(
        f"Track '{track.name}' ({track.length:.1f} m): racing line and start regions "
        f"(R1 front-most)"
    )
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    _save(fig, path)


def find_overtake(bench_dirs) -> dict | None:
    """The benchmark race to animate: the ego starting behind (R2 or R3) and winning, at the
    median margin among such races, preferring the first directory that has one; the window
    is around the ego's first gain of a position."""
    from experiments.evaluation.bench import BenchRun

    for d in bench_dirs:
        d = Path(d)
        if not (d / "manifest.json").exists():
            continue
        run = BenchRun.open(d)  # read-only: the folder's manifest stays as it was made
        cfg = run.config
        recs = [
            r for r in run.records().values() if r["ego_region"] != "R1" and r["winner"] == "ego"
        ]
        if not recs:
            continue
        recs.sort(key=lambda r: r["margin_m"])
        rec = recs[len(recs) // 2]
        states = run.states(rec["race"])
        rank = (states[:, 1:, 0] > states[:, :1, 0]).sum(axis=1)  # cars ahead of the ego
        gained = np.flatnonzero(np.diff(rank) < 0)
        t = int(gained[0]) if gained.size else 0
        return {
            "dir": str(d),
            "race": rec["race"],
            "record": rec,
            "t_overtake": t,
            "states": states,
            "config": asdict(cfg),
        }
    return None


def overtake_animation(found: dict, path: Path, before: int = 30, after: int = 50) -> dict:
    from racing_env.raceline import get_raceline
    from racing_env.render import Renderer, save_animation
    from racing_env.tracks import make_track

    track = make_track(found["config"]["track"])
    rl = get_raceline(track)
    r = Renderer(track, raceline_xy=(rl.x, rl.y), width=800, height=600, car_scale=2.0)
    st = found["states"]
    t0 = max(0, found["t_overtake"] - before)
    t1 = min(len(st), found["t_overtake"] + after)
    names = ["ego " + found["record"]["agents"][0], "O1", "O2"]
    frames = []
    for t in range(t0, t1):
        order = np.argsort(-st[t, :, 0])
        hud = [f"t = {DT * t:5.1f} s"] + [f"P{k + 1} {names[i]}" for k, i in enumerate(order)]
        frames.append(r.frame(st[t], labels=["ego", "O1", "O2"], hud=hud))
    save_animation(frames, path, fps=10)
    return {
        "dir": found["dir"],
        "race": found["race"],
        "t_overtake_s": DT * found["t_overtake"],
        "window_s": [DT * t0, DT * t1],
        "record": found["record"],
    }


def _figure(size, rows=1, cols=1):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False)
    return fig, (axes[0][0] if rows == cols == 1 else axes)


def _save(fig, path: Path) -> None:
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=130)
    tmp.replace(path)
