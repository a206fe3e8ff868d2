"""Fleet runs across processes: real-time factor and speed-up of the MPC fleet with worker
processes, and robot-steps per second of a large follower fleet.

1. ``scenarios/fleet.toml`` on the shop floor with ``--robots`` (20) MPC robots for
   ``--minutes`` (30) simulated minutes, with ``--workers`` 0, 1 and 2: wall time, real-time
   factor (simulated seconds per wall second), the speed-up of 2 workers over 1, solver
   medians, and whether the digests agree (they must: same seed, same run).
2. ``--baseline-robots`` (1000) follower robots with the greedy dispatcher,
   ``--baseline-seconds`` (60) simulated: robot-steps per wall second, in this process and with
   2 workers.

Nothing is asserted: the figures go in notes and the README.

    python scripts/bench_fleet.py [--minutes 30] [--robots 20] [--workers 0 1 2]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

from fleet.engine import World
from fleet.scenario import REPO_ROOT, load_scenario


def run(scenario, workers: int) -> tuple[dict, float]:
    t0 = time.perf_counter()
    world = World(scenario, workers=workers)
    setup = time.perf_counter() - t0
    summary = world.run().summary
    return summary, setup


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=30.0, help="simulated minutes (MPC fleet)")
    ap.add_argument("--robots", type=int, default=20)
    ap.add_argument("--workers", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--baseline-robots", type=int, default=1000)
    ap.add_argument("--baseline-seconds", type=float, default=60.0)
    ap.add_argument("--skip-mpc", action="store_true")
    args = ap.parse_args()

    base = load_scenario(REPO_ROOT / "scenarios" / "fleet.toml")
    if not args.skip_mpc:
        sc = base.override(robots=args.robots, controller="mpc", duration=args.minutes * 60.0)
        print(
            f"MPC fleet: {args.robots} robots, {args.minutes:g} simulated min on "
            f"{sc.map.name}, auction, sensing {sc.sensing_radius_m:g} m"
        )
        print(
            f"{'workers':>7} {'setup s':>8} {'run s':>8} {'RTF':>6} {'solve med ms':>12} "
            f"{'jobs done':>9} {'collisions':>10} digest"
        )
        walls: dict[int, float] = {}
        digests = set()
        for w in args.workers:
            s, setup = run(sc, w)
            wall = s["wall_time_s"]
            walls[w] = wall
            digests.add(s["digest"])
            print(
                f"{w:>7} {setup:>8.1f} {wall:>8.1f} {s['sim_time_s'] / wall:>6.2f} "
                f"{s['solver']['median_ms'] or 0:>12.2f} {s['jobs']['completed']:>9} "
                f"{s['violations']['collision']:>10} {s['digest'][:12]}"
            )
            # What could tie a run to the wall clock: solves cut by their time limit (not
            # "optimal"), rounds that timed out, agents lost.
            print(
                f"{'':>7} solver {s['solver']['termination']}, fallbacks "
                f"{s['solver']['fallbacks']}, bus timeouts {s['engine'].get('bus_timeouts', 0)}, "
                f"faults {s['faults']}"
            )
        if 1 in walls and 2 in walls:
            print(f"speed-up 2 workers vs 1: {walls[1] / walls[2]:.2f}")
        print(f"digests agree: {len(digests) == 1}")

    n = args.baseline_robots
    # The baseline: follower and greedy dispatcher (auction bids cost a path search per robot
    # and job, which a job every 0.1 s for 1000 robots turns into the whole run).
    sc = replace(
        base.override(robots=n, duration=args.baseline_seconds, dispatcher="greedy"),
        jobs=replace(base.jobs, rate_per_h=30.0 * n),
    )
    print(
        f"\nfollower fleet: {n} robots, {args.baseline_seconds:g} simulated s, greedy, "
        f"sensing {sc.sensing_radius_m:g} m"
    )
    print(f"{'workers':>7} {'setup s':>8} {'run s':>8} {'robot-steps':>11} {'steps/s':>9}")
    for w in (0, 2):
        s, setup = run(sc, w)
        steps = s["engine"]["robot_steps"]
        print(
            f"{w:>7} {setup:>8.1f} {s['wall_time_s']:>8.1f} {steps:>11} "
            f"{steps / s['wall_time_s']:>9.0f}"
        )


if __name__ == "__main__":
    main()
