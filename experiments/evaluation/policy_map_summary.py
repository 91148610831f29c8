"""A policy map's figures: per mode and track, what share of the thetas stays on track, the
pace and progress quantiles, the best thetas (``summary.json``, ``summary.md``), and the heat
maps over (zeta, q) and (zeta, s1)."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np

from experiments.evaluation.thetas import theta_box, theta_names
from experiments.infra.artifacts import (
    slug,
)

OFF_TRACK_LIMIT = 0.01
"""A theta is "off track" on a map when more than this fraction of its steps were off track."""


GOAL_SHARE = 0.05
"""The goal for the 3-car map: at most this share of the box off track (issue 12)."""


ZETA_BINS = 7


QUANTILES = (0.0, 0.05, 0.25, 0.5, 0.75, 0.95, 1.0)


def heatmap_name(mode: str, track: str) -> str:
    return f"heatmap_{mode}_{slug(track)}.png"


def _nan(v) -> float:
    return float("nan") if v is None else float(v)


def _clean(x: float):
    """JSON-safe float: NaN becomes None."""
    return None if x is None or not np.isfinite(x) else float(x)


def _group_summary(rows: list[dict], zeta_edges: np.ndarray) -> dict:
    ok = [r for r in rows if "error" not in r]
    out = {
        "thetas": len(rows),
        "errors": len(rows) - len(ok),
        "error_indices": sorted(r["index"] for r in rows if "error" in r),
    }
    if not ok:
        return out
    prog = np.array([r["progress_m"] for r in ok])
    off = np.array([r["off_track_frac"] for r in ok])
    lap = np.array([_nan(r["best_lap_s"]) for r in ok])
    zeta = np.array([r["theta"]["zeta"] for r in ok])
    bad = off > OFF_TRACK_LIMIT
    out.update(
        {
            "off_track_share": float(bad.mean()),
            "off_track_frac_mean": float(off.mean()),
            "progress_m_mean": float(prog.mean()),
            "progress_m_quantiles": {
                f"p{int(round(100 * q))}": float(v)
                for q, v in zip(QUANTILES, np.quantile(prog, QUANTILES))
            },
            "best_lap_s_median": _clean(np.nanmedian(lap)) if np.isfinite(lap).any() else None,
            "fallbacks_mean": float(np.mean([r["fallbacks"] for r in ok])),
            "restarts_mean": float(np.mean([r["restarts"] for r in ok])),
            "decision_ms_mean": float(np.mean([r["decision_ms"] for r in ok])),
        }
    )
    if "rank" in ok[0]:
        out["win_share"] = float(np.mean([r["rank"] == 1 for r in ok]))
        out["margin_m_mean"] = float(np.mean([r["margin_m"] for r in ok]))
    clean = [r for r in ok if r["off_track_frac"] <= OFF_TRACK_LIMIT]
    top = sorted(clean, key=lambda r: (-r["progress_m"], r["index"]))[:10]
    keep = (
        "index",
        "theta",
        "progress_m",
        "best_lap_s",
        "off_track_frac",
        "fallbacks",
        "restarts",
        "rank",
        "margin_m",
        "start_region",
    )
    out["top10"] = [{k: r[k] for k in keep if k in r} for r in top]
    out["best"] = out["top10"][0] if top else None
    bins = []
    idx = np.clip(np.searchsorted(zeta_edges, zeta, side="right") - 1, 0, len(zeta_edges) - 2)
    for b in range(len(zeta_edges) - 1):
        m = idx == b
        entry = {
            "zeta_lo": float(zeta_edges[b]),
            "zeta_hi": float(zeta_edges[b + 1]),
            "thetas": int(m.sum()),
        }
        if m.any():
            entry.update(
                {
                    "progress_m_mean": float(prog[m].mean()),
                    "best_lap_s_median": _clean(np.nanmedian(lap[m]))
                    if np.isfinite(lap[m]).any()
                    else None,
                    "laps_mean": float(np.mean([r["laps"] for r, mm in zip(ok, m) if mm])),
                    "off_track_frac_mean": float(off[m].mean()),
                    "off_track_share": float(bad[m].mean()),
                }
            )
        bins.append(entry)
    out["by_zeta"] = bins
    return out


def summarise(rows: list[dict], config) -> dict:
    """Per mode and track: share of the box off track (more than :data:`OFF_TRACK_LIMIT` of
    the steps), the best theta among those on track and its progress, progress quantiles [m],
    the top 10 thetas on track by progress, and progress / best lap / off-track by zeta bins;
    per mode over all tracks: the share of rows off track and of thetas off track on any.
    ``config`` is the map's :class:`~experiments.evaluation.policy_map.PolicyMapConfig`."""
    THETA_NAMES = theta_names(config.space)
    if not rows:
        raise ValueError("no finished rows to summarise")
    low, high = theta_box(config.space)
    iz = THETA_NAMES.index("zeta")
    zeta_edges = np.linspace(low[iz], high[iz], ZETA_BINS + 1)
    expected = config.thetas * len(config.tracks) * len(config.modes)
    out = {
        "config": asdict(config),
        "theta_names": list(THETA_NAMES),
        "theta_low": low.tolist(),
        "theta_high": high.tolist(),
        "off_track_limit": OFF_TRACK_LIMIT,
        "goal_share": GOAL_SHARE,
        "rows": len(rows),
        "complete": len(rows) == expected,
        "maps": {},
    }
    for mode in config.modes:
        per = {}
        for track in config.tracks:
            sub = [r for r in rows if r["mode"] == mode and r["track"] == track]
            if sub:
                per[track] = _group_summary(sub, zeta_edges)
        ok = [r for r in rows if r["mode"] == mode and "error" not in r]
        if ok:
            bad_any = {}
            for r in ok:
                bad_any[r["index"]] = (
                    bad_any.get(r["index"], False) or r["off_track_frac"] > OFF_TRACK_LIMIT
                )
            per["all"] = {
                "rows": len(ok),
                "off_track_share": float(
                    np.mean([r["off_track_frac"] > OFF_TRACK_LIMIT for r in ok])
                ),
                "thetas": len(bad_any),
                "off_track_any_track_share": float(np.mean(list(bad_any.values()))),
            }
        out["maps"][mode] = per
    return out


def _f(v, fmt="{:.2f}") -> str:
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else fmt.format(v)


def summary_markdown(s: dict) -> str:
    c = s["config"]
    names = s["theta_names"]
    box = ", ".join(
        f"{n} {lo:g}..{hi:g}" for n, lo, hi in zip(names, s["theta_low"], s["theta_high"])
    )
    lim = 100 * s["off_track_limit"]
    lines = [
        "# Policy map",
        "",
        f"{c['thetas']} thetas (scrambled Sobol, seed {c['seed']}) over the box {box}; "
        f"{c['steps']} steps of 0.1 s per run; modes {', '.join(c['modes'])} on "
        f"{', '.join('`' + t + '`' for t in c['tracks'])}; race opponents: two "
        f"`{c['opponents']}`. {s['rows']} rows" + ("" if s["complete"] else " (partial)") + ".",
        "",
        f"Off track: more than {lim:g}% of a run's steps off track (goal for the race map: "
        f"at most {100 * s['goal_share']:g}% of the box). Best and top 10 are among the "
        f"thetas on track, by progress. Best lap: fastest lap after the first.",
        "",
        "| mode | track | thetas | off-track share | progress p5 / p50 / p95 [m] "
        f"| best theta ({', '.join(names)}) | its progress [m] | errors |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for mode, per in s["maps"].items():
        for track, g in per.items():
            if track == "all":
                continue
            if "progress_m_quantiles" not in g:
                lines.append(
                    f"| {mode} | `{track}` | {g['thetas']} | - | - | - | - | {g['errors']} |"
                )
                continue
            q = g["progress_m_quantiles"]
            b = g["best"]
            bt = ", ".join(f"{b['theta'][n]:.3g}" for n in names) if b else "-"
            lines.append(
                f"| {mode} | `{track}` | {g['thetas']} | {100 * g['off_track_share']:.1f}% "
                f"| {q['p5']:.1f} / {q['p50']:.1f} / {q['p95']:.1f} | {bt} "
                f"| {_f(b['progress_m'] if b else None, '{:.1f}')} | {g['errors']} |"
            )
        if "all" in per:
            a = per["all"]
            lines.append(
                f"| {mode} | all tracks | {a['thetas']} | {100 * a['off_track_share']:.1f}% "
                f"of runs, {100 * a['off_track_any_track_share']:.1f}% of thetas on "
                f"some track | | | | |"
            )
    for mode, per in s["maps"].items():
        for track, g in per.items():
            if track == "all" or "progress_m_quantiles" not in g:
                continue
            q = g["progress_m_quantiles"]
            lines += [
                "",
                f"## {mode} on `{track}`",
                "",
                "Progress quantiles [m]: "
                + ", ".join(f"{k} {v:.1f}" for k, v in q.items())
                + f". Mean fallbacks {g['fallbacks_mean']:.2f}, restarts "
                f"{g['restarts_mean']:.1f}, decision {g['decision_ms_mean']:.2f} ms per run.",
            ]
            if "win_share" in g:
                lines[-1] += (
                    f" Theta car wins {100 * g['win_share']:.0f}% of the races, mean "
                    f"margin {g['margin_m_mean']:+.2f} m."
                )
            if g["error_indices"]:
                lines[-1] += f" Errors at theta indices {g['error_indices']}."
            race = "win_share" in g
            lines += [
                "",
                "| # | index | " + " | ".join(names) + " | progress m | best lap s "
                "| off-track % | fallbacks" + (" | start | rank | margin m" if race else "") + " |",
                "|" + "---|" * (len(names) + 6 + (3 if race else 0)),
            ]
            for i, r in enumerate(g["top10"], 1):
                lines.append(
                    f"| {i} | {r['index']} | "
                    + " | ".join(f"{r['theta'][n]:.3g}" for n in names)
                    + f" | {r['progress_m']:.2f} | {_f(r['best_lap_s'])} "
                    f"| {100 * r['off_track_frac']:.1f} | {r['fallbacks']}"
                    + (
                        f" | {r['start_region']} | {r['rank']} | {r['margin_m']:+.2f}"
                        if race
                        else ""
                    )
                    + " |"
                )
            lines += [
                "",
                "| zeta | thetas | progress m (mean) | best lap s (median) | laps (mean) "
                "| off-track % (mean) | off-track share |",
                "|---|---|---|---|---|---|---|",
            ]
            for b in g["by_zeta"]:
                rng = f"{b['zeta_lo']:.3f}-{b['zeta_hi']:.3f}"
                if not b["thetas"]:
                    lines.append(f"| {rng} | 0 | - | - | - | - | - |")
                    continue
                lines.append(
                    f"| {rng} | {b['thetas']} | {b['progress_m_mean']:.2f} "
                    f"| {_f(b['best_lap_s_median'])} | {b['laps_mean']:.1f} "
                    f"| {100 * b['off_track_frac_mean']:.2f} "
                    f"| {100 * b['off_track_share']:.0f}% |"
                )
            lines += ["", f"![{mode} on {track}]({heatmap_name(mode, track)})"]
    return "\n".join(lines) + "\n"


def binned_means(x, y, v, x_range, y_range, bins: int):
    """Means of ``v`` over a ``bins`` x ``bins`` grid of (x, y) within the ranges; returns
    ``(x_edges, y_edges, means (bins_y, bins_x))`` with NaN in empty cells. Points on an
    upper edge fall in the last cell."""
    x, y, v = (np.asarray(a, dtype=float) for a in (x, y, v))
    xe = np.linspace(*x_range, bins + 1)
    ye = np.linspace(*y_range, bins + 1)
    ix = np.clip(np.searchsorted(xe, x, side="right") - 1, 0, bins - 1)
    iy = np.clip(np.searchsorted(ye, y, side="right") - 1, 0, bins - 1)
    total = np.zeros((bins, bins))
    count = np.zeros((bins, bins))
    np.add.at(total, (iy, ix), v)
    np.add.at(count, (iy, ix), 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(count > 0, total / count, np.nan)
    return xe, ye, means


def heat_bins(n: int) -> int:
    """Cells per axis for ``n`` samples: about 4 samples per cell, 2 to 10 cells."""
    return int(np.clip(round(np.sqrt(n / 4.0)), 2, 10))


def plot_heatmaps(rows: list[dict], path, title: str, low, high, dpi: int = 120) -> Path:
    """Write a PNG of binned means of progress [m] and off-track fraction over (zeta, q) and
    (zeta, s1) for the rows of one map (rows with ``error`` are left out). Uses matplotlib's
    Agg canvas directly, so it never touches the global backend."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from agents.reference import THETA_NAMES

    ok = [r for r in rows if "error" not in r]
    if not ok:
        raise ValueError(f"no finished rows to plot for {title}")
    rng = {n: (lo, hi) for n, lo, hi in zip(THETA_NAMES, low, high)}
    th = {n: np.array([r["theta"][n] for r in ok]) for n in THETA_NAMES}
    metrics = (
        ("progress_m", "progress [m]", "viridis"),
        ("off_track_frac", "off-track fraction", "magma_r"),
    )
    bins = heat_bins(len(ok))
    fig = Figure(figsize=(10, 8))
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 2)
    for row, (key, label, cmap) in enumerate(metrics):
        v = np.array([r[key] for r in ok], dtype=float)
        grids = {
            other: binned_means(th["zeta"], th[other], v, rng["zeta"], rng[other], bins)
            for other in ("q", "s1")
        }
        both = np.concatenate([g[2].ravel() for g in grids.values()])
        vmin, vmax = float(np.nanmin(both)), float(np.nanmax(both))  # one scale per row
        if key == "off_track_frac":  # 0 = on track; the scale shows the 1% limit
            vmin, vmax = 0.0, max(vmax, 2 * OFF_TRACK_LIMIT)
        for col, (other, (xe, ye, m)) in enumerate(grids.items()):
            ax = axes[row, col]
            mesh = ax.pcolormesh(
                xe,
                ye,
                np.ma.masked_invalid(m),
                cmap=cmap,
                shading="flat",
                vmin=vmin,
                vmax=vmax if vmax > vmin else vmin + 1e-9,
            )
            ax.plot(th["zeta"], th[other], ".", color="0.5", ms=2)
            fig.colorbar(mesh, ax=ax, label=f"{label} (bin mean)")
            ax.set_xlabel("zeta")
            ax.set_ylabel(other)
    fig.suptitle(f"Policy map, {title}: {len(ok)} thetas, {bins} x {bins} bins")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    return path
