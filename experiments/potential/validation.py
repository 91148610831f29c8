"""Validation of a trained alpha-potential on held-out races: the approximation gap's
statistics (potential differences against value differences of unilateral deviations), the
paired rollouts that check them by simulation, and the metrics' text."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor

import numpy as np
from tqdm import tqdm

from experiments.infra.parallel import pin_worker


def gap_statistics(dphi, dv, vr: float) -> dict:
    """Statistics of the approximation gap of deviations with potential changes ``dphi`` and
    value changes ``dv`` (arrays (n,)), relative to the value range ``vr`` [m]: median, 95th
    percentile and maximum of ``|dPhi - dV| / vr``, alpha (the largest absolute gap), the
    share within 10%, those of a constant potential (``|dV| / vr``), a histogram and the sign
    agreement of dPhi and dV."""
    rel, base = np.abs(dphi - dv) / vr, np.abs(dv) / vr
    q = lambda a, p: float(np.percentile(a, p))
    return {
        "gap_rel_median": q(rel, 50),
        "gap_rel_p95": q(rel, 95),
        "gap_rel_max": float(rel.max()),
        "alpha": float(np.abs(dphi - dv).max()),
        "gap_rel_within_10pct": float(np.mean(rel <= 0.10)),
        "const_rel_median": q(base, 50),
        "const_rel_p95": q(base, 95),
        "gap_rel_histogram": np.histogram(rel, bins=20, range=(0, 0.2))[0].tolist(),
        "sign_agreement": float(np.mean(np.sign(dphi) == np.sign(dv))),
    }


def discounted_rollout(
    track: str,
    x,
    thetas,
    car: int,
    steps: int,
    gamma: float,
    vehicle_class: str = "orca",
    wake: float | None = None,
):
    """``(G, x_end)``: car ``car``'s gamma-discounted return over ``steps`` of MPC cars with
    ``thetas`` (N, dim) of one policy space from the joint state ``x`` (N, 6) on ``track`` (a
    name, built at ``vehicle_class``'s scale, raced with ``wake``: None the class's), and the
    joint state after them (N, 6) for a bootstrap with V."""
    from experiments.potential.collect import rollout_from_state

    states, rewards = rollout_from_state(track, x, thetas, steps, vehicle_class, wake)
    disc = gamma ** np.arange(len(rewards))
    return float(disc @ rewards[:, car]), states[-1]


def paired_rollouts(jobs: list[tuple], threads: int, progress_bar: bool) -> list[tuple]:
    """:func:`discounted_rollout` of every job ``(track, x, thetas, car, steps, gamma)`` (or
    those and ``vehicle_class, wake``) on a pool of ``threads`` worker processes, each pinned
    to one thread per library; the ``(G, x_end)`` of each job, in the jobs' order. The thetas
    (N, dim) are the caller's deviations, drawn in the box of the data's policy space (by
    :func:`experiments.potential.train.sample_deviations` or
    :class:`experiments.potential.train_general.FamilyDeviations`)."""
    with ProcessPoolExecutor(max_workers=threads, initializer=pin_worker) as pool:
        return list(
            tqdm(
                pool.map(discounted_rollout, *zip(*jobs)),
                total=len(jobs),
                desc="paired rollouts",
                disable=not progress_bar,
            )
        )


def rollout_statistics(dphi, dv, dG, vr: float, steps: int) -> dict:
    """Statistics of paired rollouts of ``steps`` steps with simulated (bootstrapped) return
    differences ``dG``, potential changes ``dphi`` and value changes ``dv`` (arrays (n,)),
    relative to the value range ``vr`` [m]: median and 95th percentile of
    ``|dPhi - dG| / vr``, the medians of ``|dV - dG| / vr`` and of a constant potential
    (``|dG| / vr``), and the sign agreement of dPhi and dG."""
    return {
        "rollout_pairs": len(dG),
        "rollout_steps": steps,
        "rollout_phi_rel_median": float(np.median(np.abs(dphi - dG)) / vr),
        "rollout_phi_rel_p95": float(np.percentile(np.abs(dphi - dG), 95) / vr),
        "rollout_value_rel_median": float(np.median(np.abs(dv - dG)) / vr),
        "rollout_const_rel_median": float(np.median(np.abs(dG)) / vr),
        "rollout_sign_agreement_phi": float(np.mean(np.sign(dphi) == np.sign(dG))),
    }


def summary_text(m: dict) -> str:
    lines = [
        f"value network: held-out R^2 {m['value_val_r2']:.3f}",
        f"approximation gap |dPhi - dV_i| / range(V) on {m['val_pairs']} held-out deviations: "
        f"median {100 * m['gap_rel_median']:.2f}%, 95th pct {100 * m['gap_rel_p95']:.2f}%, "
        f"max {100 * m['gap_rel_max']:.1f}% (alpha = {m['alpha']:.4f}); "
        f"{100 * m['gap_rel_within_10pct']:.1f}% within 10%",
        f"constant potential: median {100 * m['const_rel_median']:.2f}%, "
        f"95th pct {100 * m['const_rel_p95']:.2f}%",
    ]
    if "rollout_pairs" in m:
        lines.append(
            f"paired rollouts ({m['rollout_pairs']}): |dPhi - dG_sim| / range median "
            f"{100 * m['rollout_phi_rel_median']:.2f}% (|dV - dG_sim| "
            f"{100 * m['rollout_value_rel_median']:.2f}%, constant "
            f"{100 * m['rollout_const_rel_median']:.2f}%)"
        )
    lines.append(f"training {m['train_seconds']:.0f} s, total {m['total_seconds']:.0f} s")
    return "\n".join(lines)
