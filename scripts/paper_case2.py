"""Case study 2 of the MAMbot MPC paper in simulation, beside the paper's Table 2.

Runs the six bump-track scenarios (fixed 0.2 ... 1.0 m/s and the varying strategy): the robot
prints the prism while shuttling along the L-shaped track; afterwards the quality model judges
the part. For each run: distance driven and angle turned while printing, the predicted worst
dimensional error and the outcome, beside the paper's figures.

    .venv/bin/python scripts/paper_case2.py [--out runs/paper_case2] [--only v04 varying]
"""

from __future__ import annotations

import argparse
import csv
import math
from importlib.resources import files
from pathlib import Path

import numpy as np

from fleet.engine import World
from fleet.scenario import REPO_ROOT, load_scenario

RUNS = ("v02", "v04", "v06", "v08", "v10", "varying")
#: The paper's run names in fleet/printing/data/table2_runs.csv, by our scenario tag.
PAPER_RUN = {"v02": "0.2", "v04": "0.4", "v06": "0.6", "v08": "0.8", "v10": "1.0"}
#: Our outcomes in the paper's words.
PAPER_WORD = {"good": "pass", "defective": "defect", "failed": "fail"}


def paper_table() -> dict[str, dict[str, str]]:
    """The paper's Table 2 per run: distance_m, turn_rad, outcome, worst |error| (mm)."""
    data = files("fleet.printing") / "data"
    with (data / "table2_runs.csv").open(encoding="utf-8") as fh:
        runs = {row["run"]: row for row in csv.DictReader(fh)}
    with (data / "table2.csv").open(encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            if row["error_mm"]:
                run = runs[row["run"]]
                worst = max(float(run.get("worst_mm") or 0.0), abs(float(row["error_mm"])))
                run["worst_mm"] = f"{worst:.2f}"
    return runs


def run_one(tag: str, out: Path | None) -> dict[str, float | str | None]:
    """Simulate one scenario; figures of its (single) print."""
    scenario = load_scenario(REPO_ROOT / "scenarios" / f"paper_case2_{tag}.toml")
    world = World(scenario)
    result = world.run()
    if out is not None:
        world.write(out / tag)
    rec = world.jobs[0]
    start, end = rec.print_start_s, rec.print_end_s
    assert start is not None and end is not None and rec.robot is not None
    t, xy, _ = world.recorder.trajectories[rec.robot].arrays()
    inside = (t >= start - 1e-9) & (t <= end + 1e-9)
    path = xy[inside]
    distance = float(np.sum(np.hypot(*np.diff(path, axis=0).T))) if len(path) > 1 else 0.0
    q = rec.quality
    return {
        "print_s": end - start,
        "distance_m": distance,
        "turn_rad": rec.turned_rad,
        "error_mm": None if q is None else q.error_mm,
        "outcome": None if q is None else PAPER_WORD[q.outcome],
        "violations": sum(result.summary["violations"].values()),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("runs/paper_case2"))
    parser.add_argument("--only", nargs="+", choices=RUNS, default=list(RUNS))
    parser.add_argument("--no-write", action="store_true", help="do not write run directories")
    args = parser.parse_args(argv)
    paper = paper_table()
    header = (
        f"{'run':>8} {'print':>6} | {'distance m':>17} {'ratio':>5} | {'turned rad':>15} "
        f"| {'worst error mm':>15} | {'outcome':>13}"
    )
    print(header)
    print(
        f"{'':>8} {'s':>6} | {'ours':>8} {'paper':>8} {'':>5} | {'ours':>7} {'paper':>7} "
        f"| {'ours':>7} {'paper':>7} | {'ours':>6} {'paper':>6}"
    )
    print("-" * len(header))
    same_pattern = True
    within = True
    for tag in args.only:
        ours = run_one(tag, None if args.no_write else args.out)
        ref = paper[PAPER_RUN.get(tag, tag)]
        ref_d = float(ref["distance_m"]) if ref["distance_m"] else math.nan
        ref_turn = float(ref["turn_rad"]) if ref["turn_rad"] else math.nan
        ratio = ours["distance_m"] / ref_d if math.isfinite(ref_d) else math.nan
        if math.isfinite(ratio) and abs(ratio - 1.0) > 0.10:
            within = False
        if ours["outcome"] != ref["outcome"]:
            same_pattern = False
        err = "-" if ours["error_mm"] is None else f"{ours['error_mm']:.3f}"
        print(
            f"{tag:>8} {ours['print_s']:>6.0f} | {ours['distance_m']:>8.1f} {_num(ref_d):>8} "
            f"{_num(ratio, '.3f'):>5} | {ours['turn_rad']:>7.1f} {_num(ref_turn):>7} | "
            f"{err:>7} {ref.get('worst_mm') or '-':>7} | {ours['outcome']:>6} {ref['outcome']:>6}"
        )
        if ours["violations"]:
            print(f"         {ours['violations']} safety violations")
    print()
    print(f"every distance within 10% of the paper's: {'yes' if within else 'NO'}")
    print(f"same pass/defect/fail pattern as the paper: {'yes' if same_pattern else 'NO'}")
    return 0 if within and same_pattern else 1


def _num(value: float, fmt: str = ".1f") -> str:
    return "-" if not math.isfinite(value) else format(value, fmt)


if __name__ == "__main__":
    raise SystemExit(main())
