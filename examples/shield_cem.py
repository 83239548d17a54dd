"""Train behind a shield: the cross-entropy method (CEM) over a linear policy on the force-regulation task.

Task: `softcbf_mj.env.presets.force_regulation` through Gymnasium with the normalised
option (`GymArmEnv(..., normalise=True)`): reward per env step −|F − F_target| (N),
F_target = 0.8 F_max = 0.128 N, cost info["cost"] = the fraction of the step's control
periods with F > F_max ("violation"); the policy acts every 0.1 s, the filter (when there
is one) every 1 ms between policy and plant. Observation: the "estimate" mode only (what a
controller sees: q, q̇, the command sent, the model's tip and ρ_pred), never the force.

Policy: a = tanh(W φ), φ = [observation's float keys flattened, 1] (d = 10 for the
two-segment arm), W ∈ R^{N×d}; a ∈ [−1, 1]^N is u_nom scaled onto ±150 hPa.

CEM: a Gaussian N(μ, diag σ²) over W's entries (μ = 0, σ = `--sigma` at the start); each
iteration draws `--population` policies, runs one episode each (`--episode-steps` env steps
from the straight arm at rest: deterministic), keeps the `--elite` best by return and sets
μ, σ to their mean and standard deviation (σ floored at `SIGMA_FLOOR`). The same draws
(one seeded generator per filter, seeded alike) train once with each filter of
`--filters` (default: "none" and the contact-aware energy governor "e-erg"), so the runs
differ only by the shield. A progress line on stderr (softcbf_mj.outputs.progress) counts the episodes.

Reported per iteration and filter: the population's mean episode return (Σ reward) and
mean episode cost (Σ cost; × 0.1 s it is the time above F_max, s), and the cumulative
training cost (Σ over every episode so far). The figure (`--figure`) plots both against the
iteration; the last line of output is one JSON line with every number.

    .venv/bin/python examples/shield_cem.py --figure docs/figures/shield_cem.png   # the figure in docs/environment.md
    .venv/bin/python examples/shield_cem.py --iterations 2 --population 3 --episode-steps 3   # a smoke run
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from controllers.registry import parse_params
from softcbf_mj.env import GymArmEnv, force_regulation
from softcbf_mj.outputs.progress import Progress

SIGMA_FLOOR = 0.05  # the CEM's smallest standard deviation per weight (keeps exploring)
DEFAULT_FILTERS = ("none", "e-erg:contact_aware=true")


def features(observation: dict[str, np.ndarray]) -> np.ndarray:
    """φ: the observation's float keys flattened, then 1 (the bias)."""
    return np.concatenate([np.ravel(observation[key]) for key in sorted(observation)] + [np.ones(1)])


def episode(env: GymArmEnv, weights: np.ndarray) -> tuple[float, float]:
    """(return, cost) of one episode of the policy a = tanh(W φ) from the straight arm at rest."""
    observation, _ = env.reset(seed=0)
    total_reward = total_cost = 0.0
    done = False
    while not done:
        observation, reward, terminated, truncated, info = env.step(np.tanh(weights @ features(observation)))
        total_reward += reward
        total_cost += info["cost"]
        done = terminated or truncated
    return total_reward, total_cost


def train(spec: str, iterations: int, population: int, elite: int, sigma: float, episode_steps: int, seed: int,
          bar: Progress | None = None, offset: int = 0) -> dict:
    """CEM behind the filter `spec` ("NAME" or "NAME:param=value;..."); per-iteration figures (module docstring).
    `bar` counts its episodes after the `offset` episodes of the filters before."""
    name, _, text = spec.partition(":")
    if bar is not None:
        bar.update(offset, f"{spec}: building the environment")
    env = GymArmEnv(force_regulation(filter=name, filter_params=parse_params(text), episode_steps=episode_steps),
                    normalise=True)
    observation, _ = env.reset(seed=0)
    shape = (env.action_space.shape[0], len(features(observation)))
    random = np.random.default_rng(seed)
    mean, std = np.zeros(shape), np.full(shape, sigma)
    returns, costs, cumulative, total = [], [], [], 0.0
    start = time.perf_counter()
    for iteration in range(iterations):
        draws = mean + std * random.standard_normal((population, *shape))
        rows = []
        for w in draws:
            rows.append(episode(env, w))
            offset += 1
            if bar is not None:
                bar.update(offset, f"{spec}, iteration {iteration + 1} of {iterations}")
        results = np.array(rows)
        total += float(results[:, 1].sum())
        returns.append(float(results[:, 0].mean()))
        costs.append(float(results[:, 1].mean()))
        cumulative.append(total)
        best = draws[np.argsort(results[:, 0])[::-1][:elite]]
        mean, std = best.mean(axis=0), np.maximum(best.std(axis=0), SIGMA_FLOOR)
    final_return, final_cost = episode(env, mean)
    if bar is not None:
        bar.update(offset + 1, f"{spec}, final policy")
    env.close()
    return {"filter": spec, "mean_return": returns, "mean_cost": costs, "cumulative_cost": cumulative,
            "final_policy_return": final_return, "final_policy_cost": final_cost, "episodes": iterations * population + 1,
            "env_dt_s": env.config.env_dt, "wall_s": time.perf_counter() - start}


def plot(results: list[dict], path: Path) -> None:
    """Return and cost per iteration for each filter, side by side (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 3.8), constrained_layout=True)
    for result in results:
        iterations = np.arange(1, len(result["mean_return"]) + 1)
        left.plot(iterations, result["mean_return"], marker="o", label=result["filter"])
        right.plot(iterations, result["mean_cost"], marker="o", label=result["filter"])
    left.set(xlabel="CEM iteration", ylabel="mean episode return [N·step]", title="return: −Σ |F − 0.128 N|")
    right.set(xlabel="CEM iteration", ylabel="mean episode cost [steps above F_max]", title="cost: Σ info['cost']")
    for axes in (left, right):
        axes.grid(alpha=0.3)
    right.legend(title="filter", loc="upper left", bbox_to_anchor=(1.02, 1.0))
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=100)
    plt.close(figure)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=8, help="CEM iterations (>= 1)")
    parser.add_argument("--population", type=int, default=8, help="policies per iteration (>= 2)")
    parser.add_argument("--elite", type=int, default=None, help="policies kept per iteration (default population/4, >= 1)")
    parser.add_argument("--sigma", type=float, default=0.5, help="initial standard deviation of each weight (> 0)")
    parser.add_argument("--episode-steps", type=int, default=50, help="env steps of 0.1 s per episode (>= 1)")
    parser.add_argument("--filters", default=",".join(DEFAULT_FILTERS),
                        help="comma-separated filter specs, NAME or NAME:param=value;... (default %(default)s)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--figure", type=Path, default=None, help="write the figure here (PNG, SVG, PDF by suffix)")
    args = parser.parse_args(argv)
    elite = args.elite if args.elite is not None else max(1, args.population // 4)
    for name, value, low in (("--iterations", args.iterations, 1), ("--population", args.population, 2),
                             ("--episode-steps", args.episode_steps, 1), ("--elite", elite, 1)):
        if value < low:
            parser.error(f"{name} must be >= {low}, got {value}")
    if elite > args.population:
        parser.error(f"--elite must be <= --population ({args.population}), got {elite}")
    if not args.sigma > 0:
        parser.error(f"--sigma must be > 0, got {args.sigma}")
    specs = [spec.strip() for spec in args.filters.split(",") if spec.strip()]
    per_filter = args.iterations * args.population + 1  # episodes, the final policy's included
    bar = Progress("shield_cem", max(1, len(specs) * per_filter), unit="episodes")
    results = [train(spec, args.iterations, args.population, elite, args.sigma, args.episode_steps, args.seed,
                     bar, i * per_filter) for i, spec in enumerate(specs)]
    bar.close()
    print(f"CEM on force regulation: {args.iterations} iterations × {args.population} policies (elite {elite}), "
          f"episodes of {args.episode_steps} steps of 0.1 s")
    print(f"{'filter':<26} {'iteration':>9} {'mean return':>12} {'mean cost':>10} {'cumulative cost':>15}")
    for r in results:
        for k, (ret, cost, cum) in enumerate(zip(r["mean_return"], r["mean_cost"], r["cumulative_cost"]), start=1):
            print(f"{r['filter']:<26} {k:>9d} {ret:>12.3f} {cost:>10.3f} {cum:>15.2f}")
        print(f"{r['filter']:<26} {'final μ':>9} {r['final_policy_return']:>12.3f} {r['final_policy_cost']:>10.3f} "
              f"{'':>15} ({r['wall_s']:.1f} s)")
    if args.figure is not None:
        plot(results, args.figure)
        print(f"figure: {args.figure}")
    print(json.dumps(results))


if __name__ == "__main__":
    main()
