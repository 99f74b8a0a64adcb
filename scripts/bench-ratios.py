#!/usr/bin/env python3
"""Prints criterion's results for the estimator benches as ratios to the
baseline measured in the same run (read from target/criterion).

    cargo bench --bench estimator && python3 scripts/bench-ratios.py

With a second directory (a copy of target/criterion from an earlier run), a
before/after table of the ratios of the benches both runs have:

    python3 scripts/bench-ratios.py target/criterion /tmp/criterion-before
"""
import json
import pathlib
import sys

root = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "target/criterion")
before_root = pathlib.Path(sys.argv[2]) if len(sys.argv) > 2 else None


def medians(group):
    """Median time (µs) of every bench of a group directory."""
    times = {}
    for est in group.glob("*/new/estimates.json"):
        data = json.loads(est.read_text())
        times[est.parent.parent.name] = data["median"]["point_estimate"] / 1e3  # ns -> us
    return times


groups = sorted(p for p in root.glob("estimator_*") if p.is_dir())
if not groups:
    sys.exit(f"no estimator results under {root}: run `cargo bench --bench estimator` first")
for group in groups:
    times = medians(group)
    base = times.get("baseline_sum_u16")
    print(f"\n{group.name}  (median, µs; ratio to baseline_sum_u16 of the same run)")
    print("| bench | time (µs) | × baseline |")
    print("|---|---:|---:|")
    for name, t in sorted(times.items(), key=lambda kv: kv[1]):
        ratio = f"{t / base:.1f}" if base else "n/a"
        print(f"| {name} | {t:.1f} | {ratio} |")
    if before_root is None:
        continue
    old = medians(before_root / group.name)
    old_base = old.get("baseline_sum_u16")
    if not (base and old_base):
        continue
    print(f"\n{group.name}: before ({before_root}) and after ({root}), × baseline of each run")
    print("| bench | before | after |")
    print("|---|---:|---:|")
    for name, t in sorted(times.items(), key=lambda kv: kv[1]):
        if name in old and name != "baseline_sum_u16":
            print(f"| {name} | {old[name] / old_base:.1f} | {t / base:.1f} |")
