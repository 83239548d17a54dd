"""Valve-board link over a pseudo-terminal: round-trip latency, exchanges per second, fraction acknowledged.

Usage: python tools/bench_link.py [--seconds 3] [--segments 2]
The board logic runs in its thread behind a pty, the laptop side uses pyserial, as in
`softcbf hardware --port <pty>`. Paced runs send one SETPOINT per period at 10 Hz and
100 Hz for --seconds each; the unpaced run sends back to back for --seconds. Prints the
figures (latency = first write → matching ACK), then one line of JSON.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hardware.board import ValveBoard
from hardware.link import ValveBoardLink
from hardware.transport import PtyBoardLine
from timing import emit


def _run(n: int, seconds: float, rate_hz: float | None) -> dict[str, float]:
    with PtyBoardLine(ValveBoard(n, -150.0, 150.0)) as line:
        link = ValveBoardLink(line.open_transport(), n, -150.0, 150.0)
        link.send_setpoints(np.zeros(n))  # SYNC and a first exchange, not counted
        rng = np.random.default_rng(0)
        results = []
        start = time.perf_counter()
        while (now := time.perf_counter()) - start < seconds:
            if rate_hz is not None:
                time.sleep(max(0.0, start + len(results) / rate_hz - now))
            results.append(link.send_setpoints(rng.uniform(-150, 150, n)))
        wall = time.perf_counter() - start
        link.close()
    latency = np.array([r.latency_s for r in results if r.ok])
    return {
        "exchanges": len(results),
        "exchanges_per_s": len(results) / wall,
        "acked_fraction": len(latency) / len(results),
        "latency_ms_median": 1e3 * float(np.median(latency)),
        "latency_ms_p99": 1e3 * float(np.percentile(latency, 99)),
        "retries": sum(r.attempts - 1 for r in results),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--segments", type=int, default=2)
    args = parser.parse_args()
    figures: dict[str, float | int] = {"segments": args.segments, "seconds": args.seconds}
    for name, rate in (("10Hz", 10.0), ("100Hz", 100.0), ("unpaced", None)):
        r = _run(args.segments, args.seconds, rate)
        print(
            f"{name:8s} {r['exchanges']:6d} exchanges  {r['exchanges_per_s']:8.1f}/s  acked {r['acked_fraction']:.4f}  "
            f"latency median {r['latency_ms_median']:.3f} ms  p99 {r['latency_ms_p99']:.3f} ms  retries {r['retries']}"
        )
        figures.update({f"{name}_{k}": round(float(v), 4) for k, v in r.items()})
    emit(figures)


if __name__ == "__main__":
    main()
