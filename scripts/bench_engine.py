"""Engine throughput: robot-steps per second with the baseline follower, in one process.

Runs the shop floor with 10, 100 and 1000 robots and prints, per fleet size, load and sensing,
the set-up time (World construction: map, plugins, bus), the run's wall time (simulation plus
the summary's safety check) and robot-steps per wall second, medians of --repeats runs. Two
loads:

- ``busy``: Poisson jobs, one per robot every two minutes on average, so the figure includes
  path planning (A* and the reference LP) for every trip;
- ``idle``: no jobs, robots hold at home: the cost of the engine, the bus and the controller alone.

Two sensing settings, both measured in the same run: the default scenario's (it senses:
``sensing_radius_m = 6``, so each observation lists the robots within 6 m with their plans, and
the follower yields and brakes for them), and ``off`` (0: robots see no one, as before sensing
existed). ``off/on`` is the ratio of their medians.

The machine may be shared, so each run is also set against a floor: a minimal SimPy loop of
the same number of double integrators (one process per robot, a step and a timeout per tick,
no bus, no controller), timed just before the run. ``ratio`` is the run's robot-steps/s over
the loop's (the median of the per-repeat ratios), which a busy machine slows alike; ``x rt``
is the real-time factor (simulated seconds per wall second). ``cpu s`` is the CPU time of the
run (this process: the engine and every agent), which the other jobs on a shared machine
change far less than the wall clock, and ``steps/cpu s`` the robot-steps per CPU second.
``digest`` is the start of the run's trajectory digest (the repeats' distinct ones): two
versions of the code that give the same digest drove every robot the same.

Nothing here is asserted: the figures go in notes and the README.

With ``--profile N`` each run goes under cProfile, timed by CPU time, and its N top entries,
by cumulative and by own time, are printed after it (docs/performance.md; the profiler's cost
per Python call makes the figures above it slower).

    python scripts/bench_engine.py [--sizes 10 100 1000] [--steps 100000] [--repeats 3]
                                   [--sensing default off] [--loads busy idle] [--profile N]
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import statistics
import time
from dataclasses import replace

import simpy

from fleet.engine import World
from fleet.floor import load_floor
from fleet.scenario import REPO_ROOT, JobsConfig, ScriptedJob, load_scenario


def minimal_loop(robots: int, steps: int, period: float) -> float:
    """Robot-steps per wall second of a bare SimPy loop: `robots` discrete double integrators
    (``p += dt v; v += dt u``, u a constant), one process each, for about `steps` steps."""
    env = simpy.Environment()

    def robot(i: int):
        x, y, vx, vy, ax, ay = float(i), 0.0, 0.0, 0.0, 0.01, -0.01
        while True:
            x, y, vx, vy = x + period * vx, y + period * vy, vx + period * ax, vy + period * ay
            yield env.timeout(period)

    for i in range(robots):
        env.process(robot(i))
    ticks = max(1, steps // robots)
    t0 = time.perf_counter()
    env.run(until=ticks * period - period / 2)  # exactly `ticks` steps per robot
    return robots * ticks / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 100, 1000])
    ap.add_argument("--steps", type=int, default=100_000, help="robot-steps per run (about)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument(
        "--sensing", nargs="+", choices=["default", "off"], default=["default", "off"],
        help="the default scenario's sensing radius, none, or both (the default)",
    )  # fmt: skip
    ap.add_argument("--loads", nargs="+", choices=["busy", "idle"], default=["busy", "idle"])
    ap.add_argument("--profile", type=int, default=0, metavar="N", help="print N top entries")
    args = ap.parse_args()

    base = load_scenario(REPO_ROOT / "scenarios" / "default.toml")
    floor = load_floor(base.map)
    print(f"map {floor.name}: {len(floor.regions)} regions; controller follower, dispatcher greedy")
    radius = {"default": base.sensing_radius_m, "off": 0.0}
    print(
        f"{'robots':>7} {'load':>5} {'sensing':>7} {'sim s':>7} {'steps':>9} {'setup s':>8} "
        f"{'run s':>8} {'steps/s':>10} {'x rt':>6} {'loop/s':>9} {'ratio':>7} {'off/on':>7} "
        f"{'cpu s':>8} {'steps/cpu s':>11} {'digest':>12}"
    )
    never = JobsConfig(mode="scripted", scripted=(ScriptedJob(1e12, floor.spec.stations[-1].name),))
    for n, load in [(n, load) for n in args.sizes for load in args.loads]:
        duration = max(10.0, args.steps * base.robots[0].period_s / n)
        # Plain deliveries: the default scenario's parts and print caps would make this a
        # benchmark of the follower's cap policy instead of the engine.
        busy = replace(base.jobs, rate_per_h=30.0 * n, parts=())
        jobs = busy if load == "busy" else never
        sc = replace(base.override(robots=n, duration=duration), jobs=jobs, parts={}, print_caps={})
        rate_of: dict[str, float] = {}
        for sensing in args.sensing:
            sensed = replace(sc, sensing_radius_m=radius[sensing])
            setups, runs, rates, loops, ratios, cpus, digests = [], [], [], [], [], [], []
            for _ in range(args.repeats):
                loops.append(minimal_loop(n, args.steps, base.robots[0].period_s))
                t0 = time.perf_counter()
                world = World(sensed, floor)
                t1 = time.perf_counter()
                profile = cProfile.Profile(time.process_time) if args.profile else None
                if profile is not None:
                    profile.enable()
                c1 = time.process_time()
                result = world.run()
                t2 = time.perf_counter()
                cpus.append(time.process_time() - c1)
                if profile is not None:
                    profile.disable()
                    stats = pstats.Stats(profile)
                    for key in ("cumulative", "tottime"):
                        stats.sort_stats(key).print_stats(args.profile)
                steps = result.summary["engine"]["robot_steps"]
                digests.append(result.summary["digest"][:12])
                setups.append(t1 - t0)
                runs.append(t2 - t1)
                rates.append(steps / (t2 - t1))
                ratios.append(rates[-1] / loops[-1])
            rate_of[sensing] = statistics.median(rates)
            label = f"{radius[sensing]:g} m" if radius[sensing] > 0 else "off"
            ratio = (
                f"{rate_of['off'] / rate_of['default']:>7.1f}" if len(rate_of) == 2 else f"{'':>7}"
            )
            print(
                f"{n:>7} {load:>5} {label:>7} {duration:>7.0f} {steps:>9} "
                f"{statistics.median(setups):>8.2f} {statistics.median(runs):>8.2f} "
                f"{rate_of[sensing]:>10.0f} "
                f"{rate_of[sensing] * base.robots[0].period_s / n:>6.2f} "
                f"{statistics.median(loops):>9.0f} {statistics.median(ratios):>7.4f} {ratio} "
                f"{statistics.median(cpus):>8.2f} {steps / statistics.median(cpus):>11.0f} "
                f"{','.join(sorted(set(digests))):>12}",
                flush=True,
            )


if __name__ == "__main__":
    main()
