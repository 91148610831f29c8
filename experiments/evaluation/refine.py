"""The control's local search: compass moves from the playoff's winner over the theta box.

The control's map samples the box with scrambled-Sobol points, and in five or six dimensions
no point comes near a corner of the box. The pace corner of the extended space (the bottom of
q and s2, the top of zeta, s1 and b) beat the map's playoff winner 17 to 10 on the playoff's
own races. A compass search (pattern search, Hooke and Jeeves 1961) reaches such corners in
a few races: from the incumbent theta, each parameter is moved down and up by ``step`` times
its range (clipped to the box: the first step, 1, puts it on the box's faces), every move
races the playoff's races, and the parameters whose best move beats the incumbent are moved
together (the pattern move). The best of the round becomes the incumbent; a round that finds
nothing better halves the step.

This module holds the search without the races: :func:`compass_search` proposes thetas and
is sent their scores, so that :func:`experiments.evaluation.control.select_best_thetas` races the
proposals of every track in one pool (and a test drives it with a score function).
"""

from __future__ import annotations

import numpy as np

from experiments.evaluation.policy_map_summary import OFF_TRACK_LIMIT


def compass_moves(theta, step: float, low, high, names) -> list[tuple[str, np.ndarray]]:
    """The compass moves of ``theta`` (dim,): each parameter ``i`` moved down, then up, by
    ``step * (high[i] - low[i])`` and clipped to ``[low[i], high[i]]``, the others kept.
    Moves that leave theta unchanged (the parameter already on that face) are left out.
    Returns ``(label, theta)`` pairs in parameter order, labels ``"<name>-"``/``"<name>+"``."""
    theta = np.asarray(theta, dtype=float)
    low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
    if not (theta.shape == low.shape == high.shape == (len(names),)):
        raise ValueError(
            f"theta, low and high must have one value per name {tuple(names)}, got shapes "
            f"{theta.shape}, {low.shape}, {high.shape}"
        )
    if not (np.isfinite(step) and 0.0 < step <= 1.0):
        raise ValueError(f"step must be in (0, 1] (a fraction of each range), got {step!r}")
    moves = []
    for i, name in enumerate(names):
        for sign, tag in ((-1.0, "-"), (1.0, "+")):
            t = theta.copy()
            t[i] = np.clip(theta[i] + sign * step * (high[i] - low[i]), low[i], high[i])
            if t[i] != theta[i]:
                moves.append((f"{name}{tag}", t))
    return moves


def score_key(score: dict) -> tuple:
    """The playoff's order, used by :func:`experiments.evaluation.control_rule.rank_playoff` and the search:
    more wins, then the larger mean margin [m], then the lower index. Smaller keys rank
    higher."""
    return (-score["wins"], -score["margin_m_mean"], score["index"])


def eligible(score: dict, steps: int) -> bool:
    """A raced theta may win when its races stayed on track: at most
    :data:`~experiments.evaluation.policy_map_summary.OFF_TRACK_LIMIT` of its ``steps`` steps per race off track,
    on average, and a finite margin."""
    return (
        np.isfinite(score["margin_m_mean"])
        and score["off_track_steps_mean"] <= OFF_TRACK_LIMIT * steps
    )


def pattern_move(theta, moves) -> np.ndarray | None:
    """The pattern move of one round: ``theta`` (dim,) with every parameter set to its best
    improving move. ``moves`` are ``(label, theta_move, improves)`` triples, best first (at
    least within each parameter; ``improves``: the move beat the incumbent), each differing
    from ``theta`` in one parameter. ``None`` when fewer than two parameters improved (the
    move would be one already raced)."""
    base = np.asarray(theta, dtype=float)
    theta = base.copy()
    moved = set()
    for _label, t, improves in moves:
        changed = np.flatnonzero(np.asarray(t, dtype=float) != base)
        if not improves or changed.size != 1:
            continue
        i = int(changed[0])
        if i not in moved:
            moved.add(i)
            theta[i] = t[i]
    return theta if len(moved) >= 2 else None


def compass_search(incumbent: dict, theta_of, low, high, names, rounds: int, steps: int):
    """The compass search from ``incumbent`` (a playoff score: ``index``, ``wins``,
    ``margin_m_mean`` [m], ``off_track_steps_mean``), as a generator.

    Each round yields twice ``(proposals, round_no)``, proposals a list of ``(label, theta)``
    to race: the compass moves (:func:`compass_moves`), then the pattern move (a list of at
    most one). Send back the scores of the proposals, in order, as ``(label, score)`` pairs
    (a theta raced before may come back with its earlier score). The best eligible score
    (:func:`eligible` with ``steps`` per race, :func:`score_key`), incumbent included, becomes
    the incumbent; a round in which the incumbent stays halves the step (1 at first: the
    box's faces). ``theta_of(score)`` gives a score's theta as an array (dim,) in ``names``'s
    order. Returns ``{"rounds": [...], "winner": score}``, each round with its ``step``, the
    incumbent's index before (``from``) and after (``to``) and every move's ``move``,
    ``index``, ``wins``, ``margin_m_mean`` and ``eligible``."""
    step, log = 1.0, []
    for round_no in range(1, rounds + 1):
        inc = incumbent
        x = theta_of(inc)
        moves = yield compass_moves(x, step, low, high, names), round_no
        ordered = sorted(moves, key=lambda m: score_key(m[1]))
        inc_key = score_key(inc)
        improving = [
            (label, theta_of(sc), eligible(sc, steps) and score_key(sc) < inc_key)
            for label, sc in ordered
        ]
        p = pattern_move(x, improving)
        pattern = yield ([] if p is None else [("pattern", p)]), round_no
        tried = list(moves) + list(pattern)
        best = min([inc] + [sc for _, sc in tried if eligible(sc, steps)], key=score_key)
        log.append(
            {
                "round": round_no,
                "step": step,
                "from": inc["index"],
                "moves": [
                    {
                        "move": label,
                        "index": sc["index"],
                        "wins": sc["wins"],
                        "margin_m_mean": sc["margin_m_mean"],
                        "eligible": bool(eligible(sc, steps)),
                    }
                    for label, sc in tried
                ],
                "to": best["index"],
            }
        )
        if best is inc:
            step /= 2
        incumbent = best
    return {"rounds": log, "winner": incumbent}
