"""The reference learning curve: distance and off-track share against steps, over seeds.

Reads ``curve.csv`` of every ``seed_*`` folder that ``examples/learn_ppo.py`` wrote and writes
``curve.png`` and ``curve.md`` beside them (means over the episodes that ended in each bin of
steps, then mean, min and max over the seeds).

    python examples/plot_learning_curve.py results/learning [--bins 10]
"""

import argparse
import csv
import json
from pathlib import Path

import numpy as np


def main(argv=None) -> Path:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", type=Path)
    p.add_argument("--bins", type=int, default=10)
    args = p.parse_args(argv)
    runs = sorted(args.folder.glob("seed_*/curve.csv"))
    if not runs:
        raise SystemExit(f"no seed_*/curve.csv under {args.folder}")
    curves = [
        {
            k: np.array([float(r[k]) for r in csv.DictReader(open(f))])
            for k in ("steps", "distance_m", "off_track_share")
        }
        for f in runs
    ]
    reports = [json.loads((f.parent / "report.json").read_text()) for f in runs]
    top = max(c["steps"].max() for c in curves)
    edges = np.linspace(0, top, args.bins + 1)
    table = {
        k: np.full((len(curves), args.bins), np.nan) for k in ("distance_m", "off_track_share")
    }
    for i, c in enumerate(curves):
        idx = np.clip(np.searchsorted(edges, c["steps"], side="left") - 1, 0, args.bins - 1)
        for b in range(args.bins):
            for k in table:
                if (idx == b).any():
                    table[k][i, b] = c[k][idx == b].mean()
    mid = edges[1:]

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for ax, k, label in (
        (axes[0], "distance_m", "distance in 50 s [m]"),
        (axes[1], "off_track_share", "share of steps off track"),
    ):
        for i, c in enumerate(curves):
            ax.plot(c["steps"], c[k], ".", ms=2, alpha=0.25, color=f"C{i}")
        ax.plot(mid, np.nanmean(table[k], 0), "k-", lw=2, label="mean of the seeds")
        ax.fill_between(
            mid,
            np.nanmin(table[k], 0),
            np.nanmax(table[k], 0),
            color="k",
            alpha=0.15,
            label="min-max of the seeds",
        )
        ax.xaxis.set_major_formatter(lambda x, _: f"{x / 1000:.0f}k")
        ax.set_xlabel("PPO env steps")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="lower right")
    fig.suptitle(
        f"PPO from scratch on HeadToHead-v2, {len(curves)} seeds (dots: training episodes)"
    )
    fig.tight_layout()
    png = args.folder / "curve.png"
    fig.savefig(png, dpi=110)

    lines = [
        "| steps up to | distance m: mean (min-max) | off-track share: mean (min-max) |",
        "|---|---|---|",
    ]
    for b in range(args.bins):
        d, o = table["distance_m"][:, b], table["off_track_share"][:, b]
        lines.append(
            f"| {int(mid[b]):,} | {np.nanmean(d):.1f} ({np.nanmin(d):.1f}-{np.nanmax(d):.1f}) | "
            f"{np.nanmean(o):.3f} ({np.nanmin(o):.3f}-{np.nanmax(o):.3f}) |"
        )
    lines += [
        "",
        "Evaluation after training (deterministic actions, 4 fresh races, statistics frozen):",
        "",
        "| seed | distance m | off-track share | training s |",
        "|---|---|---|---|",
    ]
    for r in reports:
        lines.append(
            f"| {r['seed']} | {r['evaluation']['distance_m']:.1f} | "
            f"{r['evaluation']['off_track_share']:.3f} | {r['train_s']} |"
        )
    (args.folder / "curve.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return png


if __name__ == "__main__":
    main()
