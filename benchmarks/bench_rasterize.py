"""Rasterization throughput (scans/s), batch and one at a time, for 512- and 768-beam scans.

Writes JSON (default ``benchmarks/results/rasterize.json``). The reference, measured in the same
run, is the same maths without the per-geometry cache (bearings and distances recomputed for
every scan), so the ratio shows what the cached lookup buys on whatever machine runs this.

    python benchmarks/bench_rasterize.py [--scans 4000] [--repeats 5] [--json PATH]
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
from _output import machine, write_json

from lidarflow.scan import BeamGeometry, GridSpec, Scan, _cell_lookup, rasterize, rasterize_batch

GEOMETRIES = {
    "512 beams, 180 deg, 5.6 m": BeamGeometry(512, -math.pi / 2, math.pi / 511, 0.02, 5.6),
    "768 beams, 270 deg, 11 m": BeamGeometry(768, -2.356194, 0.006135923, 0.03, 11.0),
}


def make_ranges(geom: BeamGeometry, n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.5, geom.range_max * 1.2, (n, geom.count)).astype(np.float32)
    ranges[rng.random(ranges.shape) < 0.05] = np.nan
    ranges[rng.random(ranges.shape) < 0.05] = np.inf
    return ranges


def best_rate(fn, n: int, repeats: int) -> float:
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return n / best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=4000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/rasterize.json"))
    args = parser.parse_args()
    grid = GridSpec()
    results = {}
    for name, geom in GEOMETRIES.items():
        ranges = make_ranges(geom, args.scans)
        scans = [Scan(r, geom) for r in ranges]
        rasterize_batch(ranges[:2], geom, grid)  # warm the lookup cache

        def batch(ranges=ranges, geom=geom):
            for i in range(0, len(ranges), 1000):
                rasterize_batch(ranges[i : i + 1000], geom, grid)

        def single(scans=scans):
            for s in scans:
                rasterize(s, grid)

        few = scans[: max(args.scans // 20, 50)]

        def reference(few=few):
            for s in few:
                _cell_lookup.cache_clear()
                rasterize(s, grid)

        ref = best_rate(reference, len(few), args.repeats)
        b = best_rate(batch, args.scans, args.repeats)
        s = best_rate(single, args.scans, args.repeats)
        results[name] = {
            "batch_scans_per_s": round(b),
            "single_scans_per_s": round(s),
            "reference_uncached_scans_per_s": round(ref),
            "batch_over_reference": round(b / ref, 2),
            "single_over_reference": round(s / ref, 2),
        }
        print(
            f"{name}: batch {b:,.0f}/s, one at a time {s:,.0f}/s, uncached reference {ref:,.0f}/s"
        )
    out = {
        "benchmark": "rasterize",
        "grid": grid.to_dict(),
        "scans": args.scans,
        "repeats": args.repeats,
        "machine": machine(),
        "results": results,
    }
    write_json(args.json, out)


if __name__ == "__main__":
    main()
