"""Compares gungraun's JSON lines (one summary per benchmark) with the committed baseline.

Usage: bench_gate.py RUN.jsonl BASELINE.json UPDATE(true|false) RUSTC_VERSION

Prints a table of every benchmark: the baseline's instructions, this run's, the change, and its
L1 and LL misses and estimated cycles; exits 1 when a benchmark's instructions grew by more than
the tolerance (BENCH_GATE_TOLERANCE percent, 2 by default), when a benchmark of the baseline is
missing from the run, or when one of the run has no baseline (`k`'s benchmarks are shown for the
ratios, not gated). With UPDATE true it writes the run's figures as the new baseline.
Also prints the project's instruction ratios against `k` on the same inputs.
"""

import json
import os
import sys

def metrics_of(summary):
    """The Callgrind totals of one benchmark: `profiles[].data.total.metrics` (schema v6+)."""
    for profile in summary.get("profiles", []):
        total = (profile.get("data") or {}).get("total") or {}
        if "metrics" in total:
            return total["metrics"]
    return {}


def new_value(metrics, event):
    v = metrics.get(event, {}).get("values", {}).get("new")
    return v if isinstance(v, (int, float)) else None


def figures_of(summary):
    m = metrics_of(summary)
    value = lambda e: new_value(m, e) or 0
    return {
        "instructions": new_value(m, "Ir"),
        "l1_misses": value("I1mr") + value("D1mr") + value("D1mw"),
        "ll_misses": value("ILmr") + value("DLmr") + value("DLmw"),
        "estimated_cycles": new_value(m, "EstimatedCycles"),
    }


def name_of(summary):
    module = summary.get("module_path", "")
    ident = summary.get("id") or summary.get("function_name", "")
    parts = [p for p in module.split("::")[1:] if p]
    return "::".join(parts + [str(ident)])


def main():
    run_path, baseline_path, update, rustc = sys.argv[1:5]
    tolerance = float(os.environ.get("BENCH_GATE_TOLERANCE", "2"))
    run = {}
    with open(run_path) as f:
        for line in f:
            line = line.strip()
            if not line.startswith("{"):
                continue
            s = json.loads(line)
            figures = figures_of(s)
            if figures["instructions"] is None:
                sys.exit(f"bench-gate: no instruction count in the summary of {name_of(s)}")
            run[name_of(s)] = figures
    if not run:
        sys.exit("bench-gate: the run produced no benchmark summaries")

    try:
        with open(baseline_path) as f:
            baseline = json.load(f)
    except FileNotFoundError:
        baseline = {"rustc": None, "benchmarks": {}}
    base = baseline.get("benchmarks", {})

    print(f"| benchmark | baseline | now | change | L1 misses | LL misses | estimated cycles |")
    print("|---|---|---|---|---|---|---|")
    grown, missing, unbased = [], [], []
    for name in sorted(set(base) | set(run)):
        b = base.get(name, {}).get("instructions")
        r = run.get(name)
        if r is None:
            missing.append(name)
            print(f"| {name} | {b:,} | missing | | | | |")
            continue
        n = r["instructions"]
        if b:
            change = 100.0 * (n - b) / b
            mark = " **over**" if change > tolerance else ""
            # `k`'s rows are there for the ratios; only the project's own work is gated.
            if change > tolerance and "_k::" not in name:
                grown.append(name)
            ch = f"{change:+.2f} %{mark}"
        else:
            ch = "new"
            unbased.append(name)
        fmt = lambda v: "" if v is None else f"{int(v):,}"
        print(f"| {name} | {fmt(b)} | {n:,} | {ch} | {fmt(r['l1_misses'])} | {fmt(r['ll_misses'])} | {fmt(r['estimated_cycles'])} |")

    # Instruction ratios against k on the same inputs.
    for ours, theirs, what in [
        ("fk_f32::walk_16_frames", "fk_k::walk_16_frames", "FK of the 31-bone skeleton, f32"),
        ("fk_f64::walk_16_frames", "fk_k::walk_16_frames", "FK of the 31-bone skeleton, f64"),
        ("limb_ik::arm_100_targets", "limb_ik_k::arm_100_targets", "IK, arm"),
        ("limb_ik::leg_100_targets", "limb_ik_k::leg_100_targets", "IK, leg"),
    ]:
        a = next((v for k, v in run.items() if k.endswith(ours)), None)
        b = next((v for k, v in run.items() if k.endswith(theirs)), None)
        if a and b:
            print(f"{what}: k ÷ this = {b['instructions'] / a['instructions']:.1f}× in instructions")

    if baseline.get("rustc") and baseline["rustc"] != rustc:
        print(f"bench-gate: the baseline was made with {baseline['rustc']}, this run with {rustc}")

    if update == "true":
        with open(baseline_path, "w") as f:
            json.dump({"rustc": rustc, "benchmarks": run}, f, indent=2, sort_keys=True)
            f.write("\n")
        print(f"bench-gate: wrote {len(run)} benchmarks to {baseline_path}")
        return
    if missing:
        sys.exit(f"bench-gate: in the baseline but not run: {', '.join(missing)}")
    if unbased:
        sys.exit(
            f"bench-gate: run but not in the baseline: {', '.join(unbased)} "
            "(scripts/bench-gate --update adds them, in the commit that adds the benchmark)"
        )
    if grown:
        sys.exit(
            f"bench-gate: {len(grown)} benchmark(s) grew by more than {tolerance} %: {', '.join(grown)} "
            "(scripts/bench-gate --update writes a new baseline, in a commit that says why)"
        )
    print(f"bench-gate: {len(run)} benchmarks within {tolerance} % of the baseline")


if __name__ == "__main__":
    main()
