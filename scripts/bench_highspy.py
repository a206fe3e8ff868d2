"""MPC solve times under several highspy versions, side by side in one run: how the lock's
highspy was chosen (docs/dependencies.md).

Give it one Python interpreter per candidate, each an environment with the project installed
and only highspy differing. It runs `scripts/bench_mpc.py --repeats 1` (case study 3, both
scenarios) under each interpreter in turn, --rounds times (A B A B ..., so every candidate sees
the same load on the machine), and prints per candidate and scenario the median over rounds of
HiGHS's median and p95 solve time, the arrivals and violations seen, and each candidate's
median against the first candidate's.

    python scripts/bench_highspy.py --pythons ENV_A/bin/python ENV_B/bin/python [--rounds 5]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
from collections import defaultdict
from pathlib import Path

BENCH = Path(__file__).resolve().parent / "bench_mpc.py"


def highspy_version(python: str) -> str:
    code = "import importlib.metadata as m; print(m.version('highspy'))"
    return subprocess.run(
        [python, "-c", code], capture_output=True, text=True, check=True
    ).stdout.strip()


def bench_rows(python: str, interface: str) -> dict[str, list[str]]:
    """One bench_mpc.py run: its table's rows by scenario (other lines, e.g. banners, skipped)."""
    done = subprocess.run(
        [python, str(BENCH), "--repeats", "1", "--interfaces", interface],
        capture_output=True, text=True, check=True, cwd=BENCH.parent.parent,
    )  # fmt: skip
    rows = {}
    for line in done.stdout.splitlines():
        cells = line.split()
        if len(cells) == 14 and cells[1] == interface:
            rows[cells[0]] = cells
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pythons", nargs="+", required=True, help="one interpreter per candidate")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--interface", default="direct", choices=["direct", "pyomo"])
    args = ap.parse_args()
    labels = [f"highspy {highspy_version(p)}" for p in args.pythons]
    # (label, scenario) -> per-round figures
    median: dict[tuple[str, str], list[float]] = defaultdict(list)
    p95: dict[tuple[str, str], list[float]] = defaultdict(list)
    arrivals: dict[tuple[str, str], set[str]] = defaultdict(set)
    violations: dict[tuple[str, str], int] = defaultdict(int)
    for r in range(args.rounds):
        for label, python in zip(labels, args.pythons, strict=True):
            for scenario, cells in bench_rows(python, args.interface).items():
                key = (label, scenario)
                median[key].append(float(cells[3]))
                p95[key].append(float(cells[4]))
                arrivals[key].add(cells[12])
                violations[key] += int(cells[13])
            print(f"round {r + 1}/{args.rounds}: {label} done", flush=True)
    print(
        f"\n{'candidate':<16} {'scenario':<16} {'rounds':>6} {'med ms':>7} {'p95 ms':>7} "
        f"{'med/1st':>7} {'p95/1st':>7} {'arrival':>8} {'viol':>4}"
    )
    for key in sorted(median, key=lambda k: (k[1], labels.index(k[0]))):
        label, scenario = key
        first = (labels[0], scenario)
        m, p = statistics.median(median[key]), statistics.median(p95[key])
        m0, p0 = statistics.median(median[first]), statistics.median(p95[first])
        print(
            f"{label:<16} {scenario:<16} {len(median[key]):>6} {m:>7.1f} {p:>7.1f} "
            f"{m / m0:>7.2f} {p / p0:>7.2f} {'/'.join(sorted(arrivals[key])):>8} "
            f"{violations[key]:>4}"
        )


if __name__ == "__main__":
    main()
