"""Benchmark robustness studies: samples per hour, 1 → 2 worker speed-up, local pool vs Dask overhead.

    .venv/bin/python tools/bench_study.py [--study studies/paper_tunings_plate_errors.toml]
                                          [--samples 10] [--duration S] [--overhead-samples 20]

1. Throughput: the first `--samples` samples of the study (default: the preset; `--duration`
   shortens its runs) on 1 and on 2 local workers: wall time, samples per hour, speed-up
   (target ≥ 1.7× on 2 cores), and the sample runner's overhead, the sample's wall time in
   the worker minus its closed loop's `wall_s` (model build, temporary time series).
2. Per-sample overhead of the backends: `--overhead-samples` samples of 0.02 s simulated time
   on the local pool and on a Dask LocalCluster (127.0.0.1, 2 worker processes), each timed
   after its workers are up (a warm-up sample first): overhead per sample =
   wall / n − mean(sample_wall_s) / 2.

Figures are noisy on a shared machine. Prints the figures and ends with one JSON line.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from dataclasses import replace
from pathlib import Path

from softcbf.study import Study, StudyStore, load_study, run_study
from timing import emit, timed

ROOT = Path(__file__).resolve().parents[1]


def _timed(study: Study, samples: int, **backend) -> tuple[float, list[dict]]:
    with tempfile.TemporaryDirectory(prefix="bench-study-") as tmp:
        _, took = timed(lambda: run_study(study, Path(tmp) / "s", samples=samples, progress=False, **backend))
        return took.wall, StudyStore.open(Path(tmp) / "s").load_rows()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--study", type=Path, default=ROOT / "studies" / "paper_tunings_plate_errors.toml")
    parser.add_argument("--samples", type=int, default=10)
    parser.add_argument("--duration", type=float, help="override the study's duration (s simulated per sample)")
    parser.add_argument("--overhead-samples", type=int, default=20)
    args = parser.parse_args()

    study = load_study(args.study)
    if args.duration is not None:
        study = replace(study, fixed={**study.fixed, "duration": args.duration})
    n = min(args.samples, study.n_samples)
    out: dict[str, float | int | str] = {"study": study.name, "samples": n,
                                         "duration_s": study.fixed.get("duration")}
    for workers in (1, 2):
        wall, rows = _timed(study, n, workers=workers)
        ok = [r for r in rows if r["status"] == "ok"]
        out[f"wall_s_{workers}w"] = wall
        out[f"samples_per_hour_{workers}w"] = 3600 * n / wall
        if workers == 1 and ok:
            out["sample_s_median"] = statistics.median(r["sample_wall_s"] for r in ok)
            out["runner_overhead_s_median"] = statistics.median(r["sample_wall_s"] - r["wall_s"] for r in ok)
        print(f"{workers} worker(s): {n} samples in {wall:.1f} s = {out[f'samples_per_hour_{workers}w']:.0f} samples/h")
    out["speedup_2w"] = out["wall_s_1w"] / out["wall_s_2w"]
    print(f"speed-up 1 -> 2 workers: {out['speedup_2w']:.2f}x (target >= 1.7x); sample median "
          f"{out.get('sample_s_median', float('nan')):.2f} s of which the runner's overhead (model build, "
          f"temporary time series) {out.get('runner_overhead_s_median', float('nan')):.3f} s")

    short = replace(study, fixed={**study.fixed, "duration": 0.02})
    m = min(args.overhead_samples, short.n_samples - 1)
    from distributed import Client, LocalCluster

    with LocalCluster(host="127.0.0.1", n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        client.submit(sum, [1]).result()  # workers up
        wall, rows = _timed(short, m, client=client)
    out["dask_overhead_s_per_sample"] = wall / m - statistics.mean(r["sample_wall_s"] for r in rows) / 2
    wall, rows = _timed(short, m, workers=2)  # includes starting the pool (spawn): a study pays it once
    out["local_overhead_s_per_sample"] = wall / m - statistics.mean(r["sample_wall_s"] for r in rows) / 2
    print(f"overhead per sample ({m} samples of 0.02 s, 2 workers): local pool "
          f"{out['local_overhead_s_per_sample'] * 1e3:.0f} ms (incl. pool start), Dask LocalCluster "
          f"{out['dask_overhead_s_per_sample'] * 1e3:.0f} ms")
    emit(out)


if __name__ == "__main__":
    main()
