"""Decision time of the alpha agent: potential maximisation + MPC, in a 3-car race, and the
maximisation against the first release's (the named baseline) on the same states.

    python benchmarks/alpha_speed.py [--model default] [--steps 300] [--quality-states 200]

Prints

* the agent's times in the race: maximisation (median, p99; goal: median <= 2 ms), MPC solve,
  whole decision;
* the maximisation on the race's recorded states and warm starts, timed interleaved with
  :meth:`PotentialModel.maximise_reference` (the first release's ascent: 6 RMS-normalised
  steps from 4 starts, BLAS at the process's thread count), and the ratio of the medians.
  Interleaving keeps the ratio meaningful on a loaded machine, where absolute times are not:
  the first release measured 3.9 ms median on the shared 2-core machine (issue 13) and 1.1 ms
  when it was quiet;
* the quality of both: the shortfall Phi_dense - Phi* from a dense search at the same states
  (the best of 4096 uniform random joint thetas and of two ascents of 40 steps from 32 starts,
  ~100x the cost), with the race's warm starts and without (the first decision of a race), as
  median, 95th percentile and maximum, in units of Phi and relative to the spread of Phi
  (Phi_dense - the median of the random thetas).
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np


def _stats(x) -> str:
    x = np.asarray(x)
    return f"median {np.median(x):.3f}, p95 {np.percentile(x, 95):.3f}, max {x.max():.3f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--model",
        default="default",
        help="the alpha cars' model: a shipped name or the path of a model.npz (default: default)",
    )
    ap.add_argument("--steps", type=int, default=300, help="steps of the race (default: 300)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the race (default: 0)")
    ap.add_argument(
        "--iterations",
        type=int,
        default=None,
        help="the agent's ascent steps per decision (default: the agent's default)",
    )
    ap.add_argument(
        "--quality-states",
        type=int,
        default=200,
        help="recorded states for the quality comparison (0: skip it)",
    )
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    import racing_env
    from agents import make_agent_spec
    from agents.alpha_agent import AlphaAgent
    from agents.mpc_agent import joint_state_from_observation

    env = racing_env.parallel_env(n_cars=3, max_cycles=args.steps)
    obs, _ = env.reset(seed=args.seed, options={"order": [1, 0, 2]})
    alpha = AlphaAgent(
        model=args.model, **({} if args.iterations is None else {"iterations": args.iterations})
    )
    cars = [alpha, make_agent_spec("mpc:zeta=0.85"), make_agent_spec("mpc:zeta=0.8")]
    for agent, aid in zip(cars, env.possible_agents):
        agent.reset(env.track, aid, args.seed)
    decision_ms, joints, warm = [], [], []
    while env.agents:
        ego, others = joint_state_from_observation(obs["car_0"], 3)
        joints.append(np.vstack([ego[None], others]))
        warm.append(alpha._theta_joint)
        t0 = time.perf_counter()
        a0 = alpha.act(obs["car_0"])
        decision_ms.append(1e3 * (time.perf_counter() - t0))
        actions = {
            "car_0": a0,
            **{a: c.act(obs[a]) for a, c in zip(env.possible_agents[1:], cars[1:])},
        }
        obs, *_ = env.step(actions)
    st = alpha.stats
    dm = np.asarray(decision_ms)
    print(f"alpha agent, {len(dm)} decisions in a 3-car race on 'default' (model {args.model!r})")
    print(
        f"  maximisation of Phi: median {st['maximise_ms_median']:.2f} ms, p99 "
        f"{st['maximise_ms_p99']:.2f} ms   (goal: median <= 2 ms; restarts {alpha.restarts}, "
        f"iterations {alpha.iterations}; first decision {alpha.cold_restarts} x "
        f"{alpha.cold_iterations})"
    )
    print(
        f"  MPC solve:           median {st['solve_ms_median']:.2f} ms, p99 {st['solve_ms_p99']:.2f} ms"
    )
    print(
        f"  whole decision:      median {np.median(dm):.2f} ms, p99 {np.percentile(dm, 99):.2f} ms"
    )

    model, track = alpha.model, env.track
    new = lambda x, w, rng: model.maximise(
        x, track, w, rng=rng, restarts=alpha.restarts, iterations=alpha.iterations
    )
    old = lambda x, w, rng: model.maximise_reference(x, track, w, rng=rng, restarts=4, iterations=6)
    t_new, t_old = [], []
    for rep in range(2):  # interleaved, warm starts of the race
        for k in range(1, len(joints)):
            for f, out in (
                ((new, t_new), (old, t_old)) if (k + rep) % 2 else ((old, t_old), (new, t_new))
            ):
                t0 = time.perf_counter()
                f(joints[k], warm[k], np.random.default_rng(k))
                out.append(1e3 * (time.perf_counter() - t0))
    mn, mo = np.median(t_new), np.median(t_old)
    print(f"  maximisation on the race's {len(joints) - 1} warm-started states, interleaved:")
    print(f"    maximise:           median {mn:.3f} ms, p99 {np.percentile(t_new, 99):.3f} ms")
    print(
        f"    maximise_reference: median {mo:.3f} ms, p99 {np.percentile(t_old, 99):.3f} ms"
        f"   (first release: restarts 4, iterations 6)"
    )
    print(f"    ratio of medians:   {mn / mo:.2f} (new / reference), {mo / mn:.2f}x faster")
    if args.quality_states <= 0:
        return

    rng = np.random.default_rng(1)
    sample = np.sort(
        rng.choice(
            np.arange(1, len(joints)), size=min(args.quality_states, len(joints) - 1), replace=False
        )
    )
    short = {key: [] for key in ("new", "old", "new_cold", "old_cold")}
    spread = []
    for k in sample:
        x, w = joints[k], warm[k]
        sp = model.space
        th = rng.uniform(sp.low, sp.high, (4096, 3, sp.dim))
        phi_rand = model.potential(np.repeat(x[None], 4096, 0), th, track)
        dense = max(
            phi_rand.max(),
            model.maximise(
                x,
                track,
                w,
                restarts=32,
                iterations=40,
                decay=0.9,
                rng=np.random.default_rng(10 * k),
            )[1],
            model.maximise_reference(
                x,
                track,
                w,
                restarts=32,
                iterations=40,
                step=0.3,
                decay=0.9,
                rng=np.random.default_rng(10 * k + 1),
            )[1],
        )
        g = np.random.default_rng(k)
        short["new"].append(dense - new(x, w, g)[1])
        short["old"].append(dense - old(x, w, np.random.default_rng(k))[1])
        short["new_cold"].append(
            dense
            - model.maximise(
                x,
                track,
                None,
                restarts=alpha.cold_restarts,
                iterations=alpha.cold_iterations,
                rng=np.random.default_rng(k),
            )[1]
        )
        short["old_cold"].append(dense - old(x, None, np.random.default_rng(k))[1])
        spread.append(dense - np.median(phi_rand))
    spread = np.asarray(spread)
    print(
        f"  shortfall Phi_dense - Phi* on {len(sample)} states of the race (spread of Phi: "
        f"median {np.median(spread):.2f}); in Phi | relative to the spread:"
    )
    for key, label in (
        ("new", "maximise, warm start"),
        ("old", "reference, warm start"),
        ("new_cold", f"maximise, cold {alpha.cold_restarts} x {alpha.cold_iterations}"),
        ("old_cold", "reference, cold 4 x 6"),
    ):
        s = np.asarray(short[key])
        print(f"    {label:<26} {_stats(s)} | {_stats(s / spread)}")


if __name__ == "__main__":
    main()
