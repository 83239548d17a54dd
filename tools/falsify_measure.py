"""Falsification against uniform random search on a box where violations are rare (docs/studies.md).

    .venv/bin/python tools/falsify_measure.py [--study studies/paper_low_plate_corner.toml] [--seeds 1,2,3,4,5]
                                              [--searches cmaes:vertices,tpe:vertices,tpe:random,cmaes:random]
                                              [--budget 40] [--random-cap 150]
                                              [--workers 2] [--out DIR]

Per search (sampler:initial design) and seed: `softcbf.study.falsify.falsify(study, budget,
seed, sampler, initial, baseline=0, stop_on_violation=True)`, the number of evaluations to its
first violation (ρ_min_meas < 0; none within the budget: "> budget"). The first search is the
default (cmaes:vertices); it runs first, then random search, then the others. Per seed, uniform
random search: the study's Monte Carlo
draws with that seed (`falsify.uniform_baseline`, in chunks of `--chunk`, stopping at the first
violation, at most `--random-cap` draws; none: "> cap"). Then the first falsification that found
a violation is replayed with `softcbf run --config DIR/worst/config.json` and its ρ_min_meas
compared, bit for bit, with the worst-case run folder's and with the search's batched row.

Medians count a search without a violation as +∞ and a random search without one as cap + 1,
both in the direction that makes the claim harder. The target: the default search
finds a violation within 40 evaluations in at least 4 of 5 seeds, and its median is at most
half of random search's. Prints a table and the verdict; ends with one JSON line.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from softcbf.study.definition import load_study
from softcbf.study.falsify import falsify, objective_value, uniform_baseline
from softcbf.study.analysis import violated

ROOT = Path(__file__).resolve().parents[1]


def _median(values: list[float]) -> float:
    return float(statistics.median(values))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--study", type=Path, default=ROOT / "studies" / "paper_low_plate_corner.toml")
    parser.add_argument("--seeds", default="1,2,3,4,5")
    parser.add_argument("--searches", default="cmaes:vertices,tpe:vertices,tpe:random,cmaes:random")
    parser.add_argument("--budget", type=int, default=40, help="evaluations per search (default 40)")
    parser.add_argument("--random-cap", type=int, default=150, help="draws per random search at most (default 150)")
    parser.add_argument("--chunk", type=int, default=12, help="random draws per round (default 12)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, help="keep the folders here (default: a temporary folder)")
    args = parser.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    samplers = args.searches.split(",")
    study = load_study(args.study)
    with tempfile.TemporaryDirectory(prefix="falsify-measure-") as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        found: dict[str, dict[int, int | None]] = {}
        walls: dict[str, float] = {}
        replay = None
        runs = [(s, seed) for s in samplers[:1] for seed in seeds] + [("random", seed) for seed in seeds] + \
               [(s, seed) for s in samplers[1:] for seed in seeds]
        for sampler, seed in runs:
            start = time.perf_counter()
            folder = out / f"{sampler.replace(':', '-')}-seed{seed}"
            if sampler == "random":
                seeded = load_study(args.study, [f"seed={seed}"])
                rows = uniform_baseline(seeded, folder, args.random_cap, args.chunk,
                                        {"workers": args.workers, "progress": False})
                first = next((int(r["sample"]) + 1 for r in rows if violated(r)), None)
                best = min((v for v in (objective_value(r, "rho_min_meas") for r in rows) if v is not None), default=None)
                n = len(rows)
            else:
                name, initial = sampler.split(":")
                result = falsify(study, folder, budget=args.budget, sampler=name, initial=initial, seed=seed,
                                 baseline=0, stop_on_violation=True, workers=args.workers, progress=False)
                first, best, n = result["first_violation"], result["best"]["value"], result["evaluations"]
                if replay is None and first is not None:
                    config = folder / "worst" / "config.json"
                    proc = subprocess.run([str(Path(sys.executable).with_name("softcbf")), "run", "--config", str(config), "--out",
                                           str(out / "replay")], capture_output=True, text=True, cwd=ROOT)
                    replayed = json.loads((out / "replay" / "summary.json").read_text())["runs"][0]["rho_min_meas"] \
                        if proc.returncode == 0 else None
                    replay = {"sampler": sampler, "seed": seed, "search_value": best,
                              "worst_run_value": result["worst"]["value"], "replayed_value": replayed,
                              "bit_for_bit": replayed == result["worst"]["value"],
                              "search_row_equal": replayed == best, "params": result["best"]["params"]}
            walls[f"{sampler}-{seed}"] = time.perf_counter() - start
            found.setdefault(sampler, {})[seed] = first
            print(f"{sampler:14s} seed {seed}: first violation at evaluation {first if first else '>' + str(n)} "
                  f"({n} evaluations, best rho_min_meas " + ("– (a filter fault or none finished)" if best is None
                                                             else f"{best:.4f}")
                  + f", {walls[f'{sampler}-{seed}']:.0f} s)", flush=True)

    def medians(sampler: str, cap: int) -> float:
        return _median([v if v is not None else (cap + 1 if sampler == "random" else math.inf)
                        for v in found[sampler].values()])

    table = {s: {"first_violation": found[s], "median": medians(s, args.random_cap if s == "random" else args.budget),
                 "within_40": sum(1 for v in found[s].values() if v is not None and v <= 40)} for s in found}
    print("\n| search | " + " | ".join(f"seed {s}" for s in seeds) + " | median | within 40 |")
    print("|---|" + "---|" * (len(seeds) + 2))
    for s, row in table.items():
        cap = args.random_cap if s == "random" else args.budget
        cells = [str(v) if v is not None else f"> {cap}" for v in row["first_violation"].values()]
        print(f"| {s} | " + " | ".join(cells) + f" | {row['median']:g} | {row['within_40']}/{len(seeds)} |")
    default = samplers[0]
    verdict = {"within_40": table[default]["within_40"] >= 4,
               "median_at_most_half_random": table[default]["median"] <= 0.5 * table["random"]["median"],
               "worst_replays": bool(replay and replay["bit_for_bit"])}
    print(f"\ndone when ({default}): {verdict}; replay: {replay}")
    print(json.dumps({"study": str(args.study), "seeds": seeds, "budget": args.budget, "random_cap": args.random_cap,
                      "workers": args.workers, "table": table, "verdict": verdict, "replay": replay,
                      "wall_s": walls}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
