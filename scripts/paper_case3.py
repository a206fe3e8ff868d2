"""Case study 3 of the paper, reproduced: both scenarios, their lower bounds, side by side.

Runs `scenarios/paper_case3_s1.toml` (spatial speed limits) and `_s2.toml` (plus print-task
caps) through the engine with the MPC, writes each run directory (with trajectory.png,
speed.png and gantt.png) under --out, computes each trip's minimum-time lower bound offline
(`fleet.study.lowerbound`, a MILP over the whole trip), and prints arrival, the paper's arrival, the
bound, arrival / bound, violations and solver figures.

    python scripts/paper_case3.py [--out runs]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fleet.engine import World
from fleet.scenario import REPO_ROOT, load_scenario
from fleet.study.lowerbound import min_time_lower_bound
from fleet.view.figures import save_run_figures

#: The paper's arrival times (s), goal-point tracking with Gurobi's MIQP.
PAPER_ARRIVAL_S = {"paper_case3_s1": 160.0, "paper_case3_s2": 223.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("runs"))
    args = ap.parse_args()
    rows = []
    for name in PAPER_ARRIVAL_S:
        scenario = load_scenario(REPO_ROOT / "scenarios" / f"{name}.toml")
        world = World(scenario)
        result = world.run()
        out = args.out / name
        world.write(out)
        save_run_figures(out, world.floor)
        robot = next(iter(world.robots.values()))
        job = scenario.jobs.scripted[0]
        goal = world.floor.station(job.station)
        schedule = scenario.print_schedule(job)
        bound = min_time_lower_bound(
            world.floor,
            robot.home,
            (goal.x, goal.y),
            v_max=robot.spec.v_max,
            a_max=robot.spec.a_max,
            dt=robot.spec.period,
            caps=None if schedule is None else schedule.caps_from(job.at_s),
            t0=job.at_s,
            tolerance=scenario.arrival_tolerance_m,
        )
        s = result.summary
        rows.append((name, s, bound, out))

    print(
        f"{'scenario':<16} {'arrival':>8} {'paper':>7} {'bound':>7} {'arr/bnd':>7} "
        f"{'violations':>10} {'solves':>6} {'med ms':>7} {'p95 ms':>7} {'max ms':>7} "
        f"{'fallbk':>6}  run directory"
    )
    for name, s, bound, out in rows:
        arrival = s["arrivals"]["r01"]
        solver = s["solver"]
        violations = sum(s["violations"].values())
        ratio = "-" if arrival is None else f"{arrival / bound.seconds:.3f}"
        shown = "never" if arrival is None else f"{arrival:.0f} s"
        tight = "" if bound.tight else "+"
        print(
            f"{name:<16} {shown:>8} {PAPER_ARRIVAL_S[name]:>5.0f} s {bound.seconds:>5.0f}{tight} s "
            f"{ratio:>7} {violations:>10d} {solver['steps']:>6d} {solver['median_ms']:>7.1f} "
            f"{solver['p95_ms']:>7.1f} {solver['max_ms']:>7.1f} {solver['fallbacks']:>6d}  {out}"
        )


if __name__ == "__main__":
    main()
