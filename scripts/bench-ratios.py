#!/usr/bin/env python3
"""Prints criterion's results for the estimator benches as ratios to the
baseline measured in the same run (read from target/criterion).

    cargo bench --bench estimator && python3 scripts/bench-ratios.py
"""
import json
import pathlib
import sys

root = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "target/criterion")
groups = sorted(p for p in root.glob("estimator_*") if p.is_dir())
if not groups:
    sys.exit(f"no estimator results under {root}: run `cargo bench --bench estimator` first")
for group in groups:
    times = {}
    for est in group.glob("*/new/estimates.json"):
        data = json.loads(est.read_text())
        times[est.parent.parent.name] = data["median"]["point_estimate"] / 1e3  # ns -> us
    base = times.get("baseline_sum_u16")
    print(f"\n{group.name}  (median, µs; ratio to baseline_sum_u16 of the same run)")
    print("| bench | time (µs) | × baseline |")
    print("|---|---:|---:|")
    for name, t in sorted(times.items(), key=lambda kv: kv[1]):
        ratio = f"{t / base:.1f}" if base else "n/a"
        print(f"| {name} | {t:.1f} | {ratio} |")
