"""Decision time of the alpha agent: potential maximisation + MPC, in a 3-car race.

    python benchmarks/alpha_speed.py [--model default] [--steps 300]

Prints the maximisation time (median, p99; goal: median <= 2 ms), the MPC solve time, the
whole decision, and how good the ascent's maximiser is: Phi(theta*) against the best of 4096
uniform random joint thetas at the same states (a brute-force baseline that costs ~100x more).
"""
from __future__ import annotations

import argparse
import time
import warnings

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="default")
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    import racing_env
    from agents import make_agent_spec
    from agents.alpha_agent import AlphaAgent
    from agents.mpc_agent import joint_state_from_observation
    from agents.reference import THETA_HIGH, THETA_LOW

    env = racing_env.parallel_env(n_cars=3, max_cycles=args.steps)
    obs, _ = env.reset(seed=args.seed, options={"order": [1, 0, 2]})
    alpha = AlphaAgent(model=args.model)
    cars = [alpha, make_agent_spec("mpc:zeta=0.85"), make_agent_spec("mpc:zeta=0.8")]
    for agent, aid in zip(cars, env.possible_agents):
        agent.reset(env.track, aid, args.seed)
    decision_ms, joints = [], []
    while env.agents:
        t0 = time.perf_counter()
        a0 = alpha.act(obs["car_0"])
        decision_ms.append(1e3 * (time.perf_counter() - t0))
        ego, others = joint_state_from_observation(obs["car_0"], 3)
        joints.append(np.vstack([ego[None], others]))
        actions = {"car_0": a0, **{a: c.act(obs[a]) for a, c in zip(env.possible_agents[1:], cars[1:])}}
        obs, *_ = env.step(actions)
    st = alpha.stats
    dm = np.asarray(decision_ms)
    print(f"alpha agent, {len(dm)} decisions in a 3-car race on 'default' (model {args.model!r})")
    print(f"  maximisation of Phi: median {st['maximise_ms_median']:.2f} ms, p99 "
          f"{st['maximise_ms_p99']:.2f} ms   (goal: median <= 2 ms; restarts {alpha.restarts}, "
          f"iterations {alpha.iterations})")
    print(f"  MPC solve:           median {st['solve_ms_median']:.2f} ms, p99 {st['solve_ms_p99']:.2f} ms")
    print(f"  whole decision:      median {np.median(dm):.2f} ms, p99 {np.percentile(dm, 99):.2f} ms")
    rng = np.random.default_rng(1)
    model, track = alpha.model, env.track
    sample = rng.choice(len(joints), size=min(40, len(joints)), replace=False)
    ratio = []
    for k in sample:
        x = joints[k]
        _, phi_star = model.maximise(x, track, rng=rng, restarts=alpha.restarts,
                                     iterations=alpha.iterations)
        th = rng.uniform(THETA_LOW, THETA_HIGH, (4096, 3, 5))
        phi_rand = model.potential(np.repeat(x[None], 4096, 0), th, track)
        lo = np.median(phi_rand)
        ratio.append((phi_star - lo) / max(phi_rand.max() - lo, 1e-12))
    ratio = np.asarray(ratio)
    print(f"  ascent vs best of 4096 random thetas (cold start, {len(sample)} states): "
          f"(Phi* - median) / (Phi_best_random - median) median {np.median(ratio):.3f}, "
          f"min {ratio.min():.3f} (>= 1: the ascent beats brute force)")


if __name__ == "__main__":
    main()
