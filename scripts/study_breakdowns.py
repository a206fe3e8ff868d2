"""The numbers of docs/availability.md: a breakdown-rate study's arms, paired by seed.

    fleet sweep studies/breakdowns.toml && fleet report runs/breakdowns
    python scripts/study_breakdowns.py runs/breakdowns        # a Markdown table on stdout

Reads the study's ``results.csv`` (one row per cell) and prints, per value of the
``breakdowns.mtbf_s`` axis, the mean over seeds of availability, breakdowns, jobs handed back by
breakdowns, print time scrapped with them (from each cell's summary.json) and good parts per
hour, and the difference in good parts per hour from the arm
without breakdowns (``mtbf_s`` 0) with its 95 % Student t interval over the seeds' paired
differences: every arm runs the same seeds, and breakdowns draw from streams of their own, so an
arm's jobs arrive as in the others.
"""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np

from fleet.study.report import t_quantile

AXIS = "breakdowns.mtbf_s"


def interval(values: list[float]) -> str:
    """``mean +- half-width`` (95 % Student t over `values`)."""
    x = np.asarray(values, dtype=float)
    if len(x) < 2:
        return f"{x.mean():.2f}"
    half = t_quantile(len(x) - 1) * x.std(ddof=1) / math.sqrt(len(x))
    return f"{x.mean():+.2f} +- {half:.2f}"


def main(study_dir: str) -> None:
    with open(Path(study_dir) / "results.csv", encoding="utf-8") as fh:
        rows = [r for r in csv.DictReader(fh) if r["status"] == "ok"]
    arms: dict[str, dict[int, dict[str, str]]] = {}
    for r in rows:
        summary = json.loads((Path(study_dir) / r["run_dir"] / "summary.json").read_text())
        r["print_scrapped_h"] = str(summary["breakdowns"]["print_scrapped_s"] / 3600.0)
        arms.setdefault(r[AXIS], {})[int(r["seed"])] = r
    base = arms.get("0", {})
    print(
        "| MTBF (s) | seeds | availability | breakdowns | jobs handed back by breakdowns "
        "| print time scrapped (h) | good parts/h "
        "| difference from no breakdowns (good parts/h, paired) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for label, by_seed in sorted(arms.items(), key=lambda a: (float(a[0]) != 0, -float(a[0]))):
        seeds = sorted(by_seed)

        def mean(column: str, by_seed: dict = by_seed, seeds: list = seeds) -> float:
            return float(np.mean([float(by_seed[s][column]) for s in seeds]))

        paired = [
            float(by_seed[s]["throughput_good_per_h"]) - float(base[s]["throughput_good_per_h"])
            for s in seeds
            if s in base
        ]
        diff = "-" if label == "0" or not paired else interval(paired)
        print(
            f"| {'none' if label == '0' else label} | {len(seeds)} | {mean('availability'):.3f} "
            f"| {mean('breakdowns'):.1f} | {mean('handed_back_breakdown'):.1f} "
            f"| {mean('print_scrapped_h'):.2f} "
            f"| {mean('throughput_good_per_h'):.2f} | {diff} |"
        )


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "runs/breakdowns")
