"""The charging-policy study's figures and numbers (studies/charging.toml, docs/availability.md).

Reads a finished sweep of the study (its results.csv and each cell's summary.json), prints a
Markdown table of what each policy gave (means over the seeds, and the paired difference of
good parts per hour with its 95 % t interval), and draws three panels: good parts per hour,
the fleet's share of time spent charging, and the lowest charge any robot fell to, each seed a
dot and each arm's mean a bar.

    python scripts/charging_figure.py runs/charging docs/img/charging.png
"""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from fleet.study.report import t_quantile  # noqa: E402

AXIS = "charging"
FIGURES = (
    ("throughput_good_per_h", "good parts per hour"),
    ("charging_share", "share of robot time charging"),
    ("min_charge_share", "lowest charge of any robot"),
)


def load(study: Path) -> dict[str, dict[int, dict[str, Any]]]:
    """arm label -> seed -> the figures of that cell."""
    arms: dict[str, dict[int, dict[str, Any]]] = {}
    with open(study / "results.csv", encoding="utf-8", newline="") as fh:
        for row in csv.DictReader(fh):
            if row["status"] != "ok":
                continue
            summary = json.loads((study / row["run_dir"] / "summary.json").read_text())
            battery = summary["battery"]
            arms.setdefault(row[AXIS], {})[int(row["seed"])] = {
                "throughput_good_per_h": summary["throughput_good_per_h"],
                "completed": summary["jobs"]["completed"],
                "charging_share": battery["charging_share"],
                "charging_s": battery["charging_s"],
                "charges": battery["charges"],
                "min_charge_share": battery["min_charge_share"],
                "energy_used_wh": battery["energy_used_wh"],
                "stranded": battery["stranded"],
                # Release to assignment (s), and the fleet's share of time idle (KPIs over time).
                "assign_wait_s": (summary.get("assign_wait_s") or {}).get("mean"),
                "idle_share": (summary.get("states") or {}).get("shares", {}).get("idle"),
            }
    return arms


def mean(values: list[float]) -> float:
    return sum(values) / len(values)


def paired(a: dict[int, dict[str, Any]], b: dict[int, dict[str, Any]], key: str) -> str:
    """Mean of b - a over the seeds both have, +- the 95 % t half-width (paired: the arms
    share their seeds, so their jobs)."""
    seeds = sorted(set(a) & set(b))
    diffs = [b[s][key] - a[s][key] for s in seeds]
    if len(diffs) < 2:
        return "-"
    m = mean(diffs)
    sd = math.sqrt(sum((d - m) ** 2 for d in diffs) / (len(diffs) - 1))
    half = t_quantile(len(diffs) - 1) * sd / math.sqrt(len(diffs))
    return f"{m:+.3g} ± {half:.3g} (n = {len(diffs)} pairs)"


def _mean_of(cells: list[dict[str, Any]], key: str, form: str) -> str:
    values = [c[key] for c in cells if c[key] is not None]
    return format(mean(values), form) if values else "-"


def table(arms: dict[str, dict[int, dict[str, Any]]]) -> str:
    rows = [
        "| policy | good parts/h | jobs completed | charging share | charges | "
        "lowest charge | energy used (Wh) | stranded | wait for a robot (s) | idle share |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for label, seeds in arms.items():
        cells = list(seeds.values())
        rows.append(
            f"| {label} | {mean([c['throughput_good_per_h'] for c in cells]):.2f} "
            f"| {mean([c['completed'] for c in cells]):.1f} "
            f"| {mean([c['charging_share'] for c in cells]):.1%} "
            f"| {mean([c['charges'] for c in cells]):.1f} "
            f"| {min(c['min_charge_share'] for c in cells):.1%} "
            f"(mean {mean([c['min_charge_share'] for c in cells]):.1%}) "
            f"| {mean([c['energy_used_wh'] for c in cells]):.0f} "
            f"| {sum(c['stranded'] for c in cells)} of {len(cells) * 4} robot-runs "
            f"| {_mean_of(cells, 'assign_wait_s', '.0f')} "
            f"| {_mean_of(cells, 'idle_share', '.1%')} |"
        )
    return "\n".join(rows)


def draw(arms: dict[str, dict[int, dict[str, Any]]], out: Path) -> None:
    labels = list(arms)
    fig, axes = plt.subplots(1, len(FIGURES), figsize=(11, 3.4))
    for ax, (key, title) in zip(axes, FIGURES, strict=True):
        for i, label in enumerate(labels):
            values = [arms[label][s][key] for s in sorted(arms[label])]
            ax.bar(i, mean(values), color="#9ecae1", width=0.6)
            ax.scatter([i] * len(values), values, color="#08519c", s=14, zorder=3)
        ax.set_xticks(range(len(labels)), labels)
        ax.set_title(title, fontsize=10)
        ax.set_ylim(bottom=0)
    fig.suptitle("Charging policies, 4 robots, 2 chargers, 90 min, 5 seeds (dots: seeds)")
    fig.tight_layout()
    fig.savefig(out, dpi=120)


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__.strip().splitlines()[-1].strip(), file=sys.stderr)
        return 2
    study, out = Path(argv[0]), Path(argv[1])
    arms = load(study)
    print(table(arms))
    names = list(arms)
    if len(names) == 2:
        a, b = (arms[n] for n in names)
        print(f"\n{names[1]} - {names[0]}, good parts/h: {paired(a, b, 'throughput_good_per_h')}")
        for key in ("completed", "charging_share", "min_charge_share", "assign_wait_s"):
            print(f"{names[1]} - {names[0]}, {key}: {paired(a, b, key)}")
    draw(arms, out)
    print(f"\nfigure: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
