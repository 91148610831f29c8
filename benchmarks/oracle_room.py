"""The room of a stored ``pass`` suite: the rollout oracle (experiments.evaluation.oracle) in
the same seats as the suite's ego, choosing among candidate thetas, against the ego's fixed
theta (the suite's own races, read from its ``races.jsonl``).

    python benchmarks/oracle_room.py results/fullsize_pass_wake1 --track tumftm:Spa \
        --region R3 --races 4 --out /tmp/room_spa_r3.jsonl

The first candidate is the suite's ego, then ``--moves M`` of its one-parameter moves
(``agents.theta.MOVES``, nested; default 4: no overtaking shift, tight
tracking, zeta 0.95, blocking); ``--candidates`` adds others (mpc specs of the same policy
space). Prints per race the ego's margin raced fixed (the suite's record) and as
the oracle, the winners, and the oracle's choices; ``--out`` keeps one JSON line per race
(run again to resume). Expensive: about ``candidates x lookahead / (every x 0.1 s)`` times the
race per race.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from pathlib import Path

import numpy as np

from agents.theta import MOVES
from experiments.evaluation.bench_config import REGIONS
from experiments.evaluation.oracle import candidate_moves, oracle_race
from experiments.evaluation.race import start_order
from experiments.infra.artifacts import append_jsonl, read_jsonl, slug


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("suite", type=Path, help="a strategy suite folder with a pass scenario")
    ap.add_argument("--track", required=True, help="a track of the suite, e.g. tumftm:Spa")
    ap.add_argument("--region", choices=REGIONS, default=None, help="only races from this region")
    ap.add_argument("--races", type=int, default=4, help="the first N races (of the region)")
    ap.add_argument(
        "--moves",
        type=int,
        default=4,
        help=f"candidates: the ego and its first M one-parameter moves of {MOVES} (default 4)",
    )
    ap.add_argument("--candidates", nargs="*", default=None, help="extra candidate mpc specs")
    ap.add_argument("--lookahead", type=float, default=3.0, help="look-ahead [s]")
    ap.add_argument("--every", type=int, default=10, help="periods between choices")
    ap.add_argument("--out", type=Path, default=None, help="JSON lines, one per race (resumed)")
    args = ap.parse_args(argv)
    config = json.loads((args.suite / "strategy.json").read_text())["config"]
    ego = config["ego"]
    records_path = args.suite / "pass" / slug(args.track) / slug(ego) / "races.jsonl"
    if not records_path.exists():
        raise SystemExit(
            f"no pass races of {ego!r} on {args.track!r} in {args.suite} ({records_path})"
        )
    records = sorted(read_jsonl(records_path), key=lambda r: r["race"])
    if args.region:
        records = [r for r in records if r["ego_region"] == args.region]
    records = records[: args.races]
    candidates = [*candidate_moves(ego, args.moves), *(args.candidates or [])]
    done = {r["race"]: r for r in read_jsonl(args.out)} if args.out else {}
    print(
        f"oracle on {args.track}, {len(candidates)} candidates, look-ahead {args.lookahead} s, "
        f"a choice every {args.every} periods; vehicle class {config['vehicle_class']}, wake {config['wake']}"
    )
    for i, c in enumerate(candidates):
        print(f"  [{i}] {c}")
    rows = []
    for rec in records:
        if rec["race"] in done:
            rows.append(done[rec["race"]])
            continue
        order = start_order(rec["start_regions"], len(rec["start_regions"]))
        t0 = time.perf_counter()
        res = oracle_race(
            candidates,
            rec["agents"][1:],
            track=args.track,
            seed=rec["seed"],
            order=order,
            steps=config["steps"],
            lookahead=args.lookahead,
            every=args.every,
            vehicle_class=config["vehicle_class"],
            wake=config["wake"],
        )
        fixed = np.asarray(rec["progress_m"])
        row = {
            "race": rec["race"],
            "region": rec["ego_region"],
            "fixed_margin_m": float(fixed[0] - fixed[1:].max()),
            "oracle_margin_m": float(res.progress[0] - res.progress[1:].max()),
            "fixed_won": bool(np.argmax(fixed) == 0),
            "oracle_won": res.winner == 0,
            "choices": dict(Counter(res.choices)),
            "candidates": candidates,
            "lookahead_s": args.lookahead,
            "seconds": round(time.perf_counter() - t0, 1),
        }
        rows.append(row)
        if args.out:
            append_jsonl(args.out, row)
        print(
            f"race {row['race']:>2} {row['region']}: margin fixed {row['fixed_margin_m']:+8.1f} m, "
            f"oracle {row['oracle_margin_m']:+8.1f} m; won fixed {row['fixed_won']}, oracle "
            f"{row['oracle_won']}; choices {row['choices']} ({row['seconds']} s)"
        )
    if rows:
        gain = np.array([r["oracle_margin_m"] - r["fixed_margin_m"] for r in rows])
        print(
            f"\n{len(rows)} races: wins fixed {sum(r['fixed_won'] for r in rows)}, oracle "
            f"{sum(r['oracle_won'] for r in rows)}; oracle's margin over the fixed theta: mean "
            f"{gain.mean():+.1f} m, min {gain.min():+.1f}, max {gain.max():+.1f}"
        )


if __name__ == "__main__":
    main()
