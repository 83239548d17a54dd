"""A random policy through the arm environment (Gymnasium API), with and without a safety filter.

The policy draws u_nom uniformly in the pressure box (±150 hPa) and holds it for
`--hold-s` s (the environment's `action_repeat` = hold_s · control_rate control periods per
env step; the filter runs every control period). Each filter sees the same action
sequences (the policy's generator is seeded per episode). Reported per filter, over all
episodes, from the state at the end of every control period: the periods with
ρ_meas < 0 (plate force above F_max = 0.16 N), the largest plate force and the least ρ_meas.
A progress line on stderr (softcbf_mj.outputs.progress) counts the env steps of all filters' episodes.

    .venv/bin/python examples/random_policy_env.py             # none, paper-cbf Low (and e-erg where the
                                                               # registry has it), 5 episodes of 10 s
    .venv/bin/python examples/random_policy_env.py --filter examples/clip_filter.py:ClipFilter \\
        --filter-params "limit_hPa=100"                        # any filter spec of controllers.registry
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from controllers.registry import FILTERS, label, parse_params
from softcbf_mj.env import GymArmEnv
from softcbf_mj.outputs.progress import Progress

ENERGY_GOVERNOR = "e-erg"


def run_filter(spec: str, params: dict[str, str], episodes: int, seconds: float, hold_s: float, control_rate: float,
               seed: int, bar: Progress | None = None, offset: int = 0) -> dict:
    """Run `episodes` episodes of the random policy through the environment filtered by `spec`; `bar` counts
    its env steps after the `offset` steps of the filters before."""
    repeat = int(round(hold_s * control_rate))
    if repeat < 1 or abs(hold_s * control_rate - repeat) > 1e-9 * repeat:
        raise ValueError(f"hold_s must be a whole number >= 1 of control periods (1/{control_rate:g} s), got {hold_s:g} s")
    if bar is not None:
        bar.update(offset, f"{spec}: building the environment")
    env = GymArmEnv(filter=spec, filter_params=params, control_rate=control_rate, action_repeat=repeat,
                    episode_steps=int(round(seconds / hold_s)))
    periods = violations = 0
    force_max, rho_min = 0.0, np.inf
    start = time.perf_counter()
    for episode in range(episodes):
        policy = np.random.default_rng([seed, episode])
        env.reset(seed=seed + episode)
        done = False
        while not done:
            u_nom = policy.uniform(env.action_space.low, env.action_space.high)
            _, _, terminated, truncated, info = env.step(u_nom)
            done = terminated or truncated
            offset += 1
            if bar is not None:
                bar.update(offset, f"{spec}, episode {episode + 1} of {episodes}")
            periods += info["periods"]
            violations += info["violation_periods"]
            force_max, rho_min = max(force_max, info["force_max_N"]), min(rho_min, info["rho_meas_min"])
    env.close()
    name = label(spec, params)
    return {"filter": name if ":" in spec or name.startswith(spec) else f"{spec} {name}", "episodes": episodes, "control_periods": periods,
            "violation_periods": violations, "violation_fraction": violations / periods, "force_max_N": force_max,
            "rho_meas_min": rho_min, "wall_s": time.perf_counter() - start}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=10.0, help="episode length [s]")
    parser.add_argument("--hold-s", type=float, default=0.5, help="how long the policy holds each action [s]")
    parser.add_argument("--control-rate", type=float, default=1000.0, help="rate of the filter's calls [Hz]")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--filter", action="append", default=[],
                        help="further filter spec (registry name, FILE.py:Factory or package.module:Factory); repeatable")
    parser.add_argument("--filter-params", action="append", default=[],
                        help='"name=value;name=value" for the --filter of the same position')
    args = parser.parse_args()
    runs = [("none", {}), ("paper-cbf", {"tuning": "Low"})]
    if ENERGY_GOVERNOR in FILTERS:  # the energy-certified reference governor, where the registry has it
        runs.append((ENERGY_GOVERNOR, {"contact_aware": "true"}))
    params = args.filter_params + [""] * (len(args.filter) - len(args.filter_params))
    runs += [(spec, parse_params(text)) for spec, text in zip(args.filter, params)]
    steps = args.episodes * int(round(args.seconds / args.hold_s))  # env steps per filter
    bar = Progress("random_policy_env", max(1, len(runs) * steps), unit_s=args.hold_s)
    results = [run_filter(spec, p, args.episodes, args.seconds, args.hold_s, args.control_rate, args.seed, bar, i * steps)
               for i, (spec, p) in enumerate(runs)]
    bar.close()
    print(f"random policy: u_nom ~ U(±150 hPa) held {args.hold_s:g} s, {args.episodes} episodes of {args.seconds:g} s, "
          f"control rate {args.control_rate:g} Hz")
    width = max(len("filter"), *(len(r["filter"]) for r in results))
    print(f"{'filter':<{width}} {'periods':>8} {'rho<0':>7} {'rho<0 [%]':>9} {'F max [N]':>9} {'rho min':>8} {'wall [s]':>8}")
    for r in results:
        print(f"{r['filter']:<{width}} {r['control_periods']:>8d} {r['violation_periods']:>7d} {100 * r['violation_fraction']:>9.2f} "
              f"{r['force_max_N']:>9.4f} {r['rho_meas_min']:>8.3f} {r['wall_s']:>8.1f}")
    print(json.dumps(results))


if __name__ == "__main__":
    main()
