"""Where and how an ego passes (``alpha-racer strategy``'s ``pass`` benches of a class other
than the paper's): the arc length of every pass and the track section it falls in (a straight
where ``|kappa|`` is small), the tow the ego got while behind and what it gained on the
straights, contact at the passes, and where the ego ended up; all from a bench folder's stored
states (:class:`~experiments.evaluation.bench.BenchRun`), so any finished bench can be read.

Sections: the lap split where ``|kappa| * L`` (``L`` the car's length) crosses
:data:`STRAIGHT_KAPPA_LENGTHS` (a radius of 100 car lengths: 470 m at full size), runs shorter
than :data:`MIN_SECTION_LENGTHS` car lengths merged into the section before them; named in lap
order ``straight 1``, ``corner 1``, ... with their arc lengths.

The wake factors are recomputed from the states with :func:`racing_env.wake.wake_factors_cars`
at the start of each control period, as the env holds them over the period.
"""

from __future__ import annotations

import numpy as np

from experiments.evaluation import metrics as race_metrics
from racing_env.track import STRAIGHT_KAPPA_LENGTHS

#: Runs of straight or corner shorter than this many car lengths join the section before.
MIN_SECTION_LENGTHS = 10.0


def track_sections(track, car_length: float, ds: float | None = None) -> list[dict]:
    """The lap's sections in order: ``{"name", "straight", "s0", "s1"}`` (arc lengths [m])."""
    ds = ds or car_length
    s = np.arange(0.0, track.length, ds)
    straight = np.abs(track.curvature(s)) * car_length < STRAIGHT_KAPPA_LENGTHS
    runs: list[list] = []  # [straight, s0, s1]
    for k, flag in enumerate(straight):
        if not runs or runs[-1][0] != bool(flag):
            if runs:
                runs[-1][2] = s[k]
            runs.append([bool(flag), s[k], s[k]])
    runs[-1][2] = track.length
    merged: list[list] = []
    for run in runs:
        if merged and (
            run[2] - run[1] < MIN_SECTION_LENGTHS * car_length or merged[-1][0] == run[0]
        ):
            merged[-1][2] = run[2]
        else:
            merged.append(run)
    counts = {True: 0, False: 0}
    out = []
    for flag, s0, s1 in merged:
        counts[flag] += 1
        kind = "straight" if flag else "corner"
        out.append(
            {"name": f"{kind} {counts[flag]}", "straight": flag, "s0": float(s0), "s1": float(s1)}
        )
    return out


def section_at(sections: list[dict], s: float) -> dict:
    """The section holding the wrapped arc length ``s``."""
    for sec in sections:
        if sec["s0"] <= s < sec["s1"]:
            return sec
    return sections[-1]


def _world(config):
    """(track, race config) of a bench config's class and wake."""
    from racing_env.class_config import race_config_for
    from racing_env.tracks import make_track

    track = make_track(config.track, vehicle_class=config.vehicle_class)
    return track, race_config_for(config.vehicle_class, wake=config.wake)


def race_passes(states, track, sections, rc, ego: int = 0) -> list[dict]:
    """The ego's passes of one race (clean or through contact): time, arc length (wrapped),
    curvature, section, the passed car, the lateral gap at the crossing, and the steps in the
    contact box with the passed car within the hold time around the crossing."""
    dt, dn, dsc = rc.dt, rc.rules.contact_dn, rc.rules.contact_ds
    hold = race_metrics.hold_steps(dt)
    out = []
    for e in race_metrics.pass_events(states, dt, dn):
        if e.passer != ego or e.kind not in ("pass", "contact"):
            continue
        frac = e.time_s / dt - (e.step - 1)
        s_cross = states[e.step - 1, ego, 0] + frac * (
            states[e.step, ego, 0] - states[e.step - 1, ego, 0]
        )
        s_wrapped = float(track.wrap(s_cross))
        sec = section_at(sections, s_wrapped)
        lo, hi = max(0, e.step - hold), min(len(states), e.step + hold + 1)
        d_s = np.abs(states[lo:hi, ego, 0] - states[lo:hi, e.passed, 0])
        d_n = np.abs(states[lo:hi, ego, 1] - states[lo:hi, e.passed, 1])
        out.append(
            {
                "time_s": round(float(e.time_s), 2),
                "s_m": round(s_wrapped, 1),
                "kappa": float(f"{float(track.curvature(s_wrapped)):.3g}"),
                "section": sec["name"],
                "straight": sec["straight"],
                "passed": int(e.passed),
                "dn_m": round(float(e.dn_m), 2),
                "through_contact": e.kind == "contact",
                "contact_steps": int(np.sum((d_s < dsc) & (d_n < dn))),
            }
        )
    return out


def race_tow(states, track, sections, rc, ego: int = 0) -> dict:
    """The tow of one race: over the control periods in which a car is ahead of the ego within
    the wake's range (:data:`racing_env.wake.WAKE_RANGE` lengths, nose to tail), the number of
    periods, the sum of the ego's drag factor, and on straights the number of such periods,
    the sum of the ego's speed and of its closing speed on the car directly ahead."""
    from racing_env.wake import WAKE_RANGE, wake_factors_cars

    L, W = rc.vehicle.length, rc.vehicle.width
    sums = dict(behind=0, drag=0.0, straight=0, v=0.0, closing=0.0)
    for x in states[:-1]:
        ahead = x[:, 0] - x[ego, 0]
        ahead[ego] = np.inf
        j = int(np.argmin(np.where(ahead > 0, ahead, np.inf)))
        if not (0 < ahead[j] < (WAKE_RANGE + 1.0) * L):
            continue
        drag, _ = wake_factors_cars(x[:, 0], x[:, 1], L, W, track.length, rc.wake)
        sums["behind"] += 1
        sums["drag"] += float(drag[ego])
        if section_at(sections, float(track.wrap(x[ego, 0])))["straight"]:
            sums["straight"] += 1
            sums["v"] += float(x[ego, 3])
            sums["closing"] += float(x[ego, 3] - x[j, 3])
    return sums


def pass_report(run, pace: dict | None = None) -> dict:
    """The report of one ``pass`` bench (a :class:`~experiments.evaluation.bench.BenchRun`):
    per-start-region wins, passes per race, every pass (:func:`race_passes`), passes per
    section, the tow (:func:`race_tow`: mean drag factor while behind, mean speed and closing
    speed on straights while behind), the ego's final ranks and gap to the winner, and with
    ``pace`` (spec -> solo progress [m]) the solo pace gap of the ego over the opponents."""
    cfg = run.config
    track, rc = _world(cfg)
    sections = track_sections(track, rc.vehicle.length)
    recs = run.records()
    passes, races = [], []
    tow = dict(behind=0, drag=0.0, straight=0, v=0.0, closing=0.0)
    for k in sorted(recs):
        rec, states = recs[k], run.states(k).astype(np.float64)
        got = race_passes(states, track, sections, rc)
        passes += [{"race": k, **p} for p in got]
        for key, v in race_tow(states, track, sections, rc).items():
            tow[key] += v
        p = np.asarray(rec["progress_m"])
        races.append(
            {
                "race": k,
                "ego_region": rec["ego_region"],
                "rank": rec["ranks"][0],
                "gap_to_winner_m": round(float(p.max() - p[0]), 1),
                "passes": len(got),
                "contacts": rec["contacts"][0],
            }
        )
    n = len(races)
    by_section = {
        sec["name"]: {
            "s0": round(sec["s0"]),
            "s1": round(sec["s1"]),
            "passes": sum(q["section"] == sec["name"] for q in passes),
        }
        for sec in sections
    }
    wins = {}
    for reg in dict.fromkeys(r["ego_region"] for r in races):
        sub = [r for r in races if r["ego_region"] == reg]
        wins[reg] = {"wins": sum(r["rank"] == 1 for r in sub), "races": len(sub)}
    ranks = [r["rank"] for r in races]
    out = {
        "spec": cfg.ego,
        "vehicle_class": cfg.vehicle_class,
        "wake": cfg.wake,
        "races": n,
        "wins_by_region": wins,
        "passes": len(passes),
        "passes_per_race": len(passes) / n if n else None,
        "passes_on_straights": sum(q["straight"] for q in passes),
        "passes_through_contact": sum(q["through_contact"] for q in passes),
        "contact_steps_at_passes": sum(q["contact_steps"] for q in passes),
        "contact_steps": sum(r["contacts"] for r in races),
        "by_section": by_section,
        "pass_list": passes,
        "tow": {
            "periods_behind": tow["behind"],
            "drag_factor_behind_mean": tow["drag"] / tow["behind"] if tow["behind"] else None,
            "periods_behind_on_straights": tow["straight"],
            "speed_behind_on_straights_mps": tow["v"] / tow["straight"]
            if tow["straight"]
            else None,
            "closing_speed_on_straights_mps": (
                tow["closing"] / tow["straight"] if tow["straight"] else None
            ),
        },
        "final_rank_counts": {str(r): ranks.count(r) for r in sorted(set(ranks))},
        "gap_to_winner_m_mean": float(np.mean([r["gap_to_winner_m"] for r in races]))
        if n
        else None,
        "race_list": races,
    }
    if pace:
        ego, opp = pace.get(cfg.ego), pace.get(cfg.opponents)
        out["solo_progress_m"] = {"ego": ego, "opponents": opp}
        out["solo_pace_gap"] = None if not ego or not opp else ego / opp - 1.0
    return out


def _f(v, fmt: str) -> str:
    return "-" if v is None else fmt.format(v)


def _sections(r: dict) -> str:
    hit = [(name, sec) for name, sec in r["by_section"].items() if sec["passes"]]
    return (
        ", ".join(f"{name} ({sec['s0']}-{sec['s1']} m): {sec['passes']}" for name, sec in hit)
        or "-"
    )


REPORT_HEADER = (
    "| track | ego | wake | wins R2 | wins R3 | passes / race | on straights | through contact "
    "| contact steps at passes | solo pace gap | drag factor behind | closing speed on "
    "straights m/s | final ranks (1/2/3) | gap to winner m | passes by section |"
)


def report_row(track: str, r: dict) -> str:
    """One line of the pass report's table."""
    w = r["wins_by_region"]
    wins = lambda reg: f"{w[reg]['wins']}/{w[reg]['races']}" if reg in w else "-"
    ranks = "/".join(str(r["final_rank_counts"].get(str(k), 0)) for k in (1, 2, 3))
    t = r["tow"]
    return (
        f"| `{track}` | `{r['spec']}` | {r['wake']:g} | {wins('R2')} | {wins('R3')} "
        f"| {_f(r['passes_per_race'], '{:.2f}')} | {r['passes_on_straights']}/{r['passes']} "
        f"| {r['passes_through_contact']} | {r['contact_steps_at_passes']} "
        f"| {_f(r.get('solo_pace_gap'), '{:+.1%}')} "
        f"| {_f(t['drag_factor_behind_mean'], '{:.3f}')} "
        f"| {_f(t['closing_speed_on_straights_mps'], '{:+.2f}')} | {ranks} "
        f"| {_f(r['gap_to_winner_m_mean'], '{:.1f}')} | {_sections(r)} |"
    )


def report_markdown(rows: list[tuple[str, dict]], title: str) -> list[str]:
    """The pass report's section of ``strategy.md``: one line per (track, report)."""
    return [
        "",
        f"## {title}",
        "",
        "Wins from each start region; passes held 1 s and clear sideways, on straights "
        f"(|kappa| L < {STRAIGHT_KAPPA_LENGTHS:g}, L the car's length); contact steps at passes: "
        "steps in the contact box with the passed car within 1 s of the crossing; solo pace gap: "
        "the ego's solo progress from the grid over the opponents' in the same time, minus 1; "
        "drag factor behind: the ego's mean drag factor while a car is ahead within the wake's "
        "range; closing speed: the ego's speed minus the car ahead's, on straights, while behind.",
        "",
        REPORT_HEADER,
        "|" + "---|" * (REPORT_HEADER.count("|") - 1),
    ] + [report_row(track, r) for track, r in rows]
