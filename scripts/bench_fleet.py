"""Fleet runs across processes: real-time factor and speed-up of the MPC fleet with worker
processes, and robot-steps per second of a large follower fleet.

1. ``scenarios/fleet.toml`` on the shop floor with ``--robots`` (20) MPC robots for
   ``--minutes`` (30) simulated minutes, with ``--workers`` 0, 1 and 2: wall time, real-time
   factor (simulated seconds per wall second), the speed-up of 2 workers over 1, solver
   medians, and whether the digests agree (they must: same seed, same run). ``--lockstep
   strict pipelined`` runs each worker count in each lockstep mode (``[bus] lockstep``; the
   digests agree within a mode, not across modes). ``--threads 1 2`` runs each with each count
   of threads per agent host (``[bus] threads``: the MPC's solves overlap) and prints each
   count's speed-up over 1 thread at the same worker count, and the fastest run's over 1
   worker and 1 thread (the digests agree across threads too).
2. ``--baseline-robots`` (1000) follower robots with the greedy dispatcher,
   ``--baseline-seconds`` (60) simulated: robot-steps per wall second, in this process and with
   2 workers.

3. With ``--balance``: why 2 workers cannot double the MPC fleet's pace. The fleet runs in this
   process once, every controller step and bid timed per robot and round; printed: how many robots
   solve per round, each robot's share of the work, and the speed-up of 2 workers over 1 that
   the lockstep allows (every round waits for its slowest worker), strict and pipelined, with
   the contiguous shares `fleet run --workers 2` uses, with interleaved shares (r01, r03, ...
   and r02, r04, ...), with a snake deal (r01, r04, r05, r08, ... and r02, r03, r06, r07, ...),
   greedy by each robot's total work (known beforehand, heaviest first to the lighter worker),
   with the best fixed split a local search finds in hindsight, with robots moved every 4 rounds
   by their past work, with each round's steps handed to the worker free first, with the best
   split of every single round, and with 3, 4 or 8 workers sharing the 2 cores. ``--rate``
   sets the job rate (a busy fleet spreads the work); ``--seed`` the scenario's seed.

4. With ``--sweep N [N ...]``: the MPC fleet at each size (issue 16), for ``--duration`` (120)
   simulated seconds with jobs at ``--per-robot-rate`` (120) per robot-hour. Per size: contacts
   (the safety checker's collision count, and the closest approach of any two robots computed
   here from the recorded trajectories, between samples too), solver fallbacks, deadlock events
   and what became of each (the blocked robot got 0.25 m closer to its goal, reached it, its job
   was handed back, or none of these by the end), jobs released and delivered, wall time; and
   those fates apart for robots with a job and for robots heading home (reached: home at the
   end, its home perhaps traded on the way: `fleet.engine.homes`), with the robots short of
   home at the end and the time of the last delivery.
   ``--release-until S`` releases jobs only for the first S simulated seconds
   (``[jobs] release_until_s``): with a longer ``--duration``, whether the fleet works off
   the whole batch (issue 16: every job delivered by the end of a long enough run).

Nothing is asserted: the figures go in notes and the README.

    python scripts/bench_fleet.py [--minutes 30] [--robots 20] [--workers 0 1 2]
        [--lockstep strict pipelined] [--threads 1 2] [--rate 4800] [--skip-baseline]
    python scripts/bench_fleet.py --balance [--minutes 10] [--rate 1200] [--robots 40]
        [--lockstep pipelined] [--seed 2]
    python scripts/bench_fleet.py --sweep 10 20 40 80 [--duration 120] [--per-robot-rate 120]
        [--out runs/sweep] [--options reuse_ticks=4] [--seed 2] [--release-until 120]
"""

from __future__ import annotations

import argparse
import math
import time
import tomllib
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from fleet.cli import _non_negative_int, _positive_float, _positive_int
from fleet.engine import World
from fleet.engine.agents import split_robots
from fleet.scenario import REPO_ROOT, PluginChoice, load_scenario


def with_lockstep(scenario, mode: str, threads: int = 1):
    """`scenario` with ``[bus] lockstep = mode`` and ``[bus] threads = threads``."""
    return replace(scenario, bus=replace(scenario.bus, lockstep=mode, threads=threads))


def run(scenario, workers: int) -> tuple[dict, float]:
    t0 = time.perf_counter()
    world = World(scenario, workers=workers)
    setup = time.perf_counter() - t0
    summary = world.run().summary
    return summary, setup


def time_work(scenario) -> tuple[list[str], np.ndarray, float, dict]:
    """Run `scenario` in this process, every controller step and bid timed per robot and round
    (CPU time): ``(robots, work, engine, summary)``, `work` seconds per round (row) and robot
    (column), `engine` the CPU seconds of the rest of the run."""
    world = World(scenario)
    assert world.host is not None
    costs: dict[tuple[str, int], float] = {}

    def timed(robot: str, method):
        # Controller steps and bids (a path search each) both run on the robot's worker.
        # CPU time of this thread: other processes on a shared machine do not inflate it.
        def call(obs, *args):
            t0 = time.thread_time()
            out = method(obs, *args)
            key = (robot, obs.tick)
            costs[key] = costs.get(key, 0.0) + time.thread_time() - t0
            return out

        return call

    for robot, controller in world.host.controllers.items():
        controller.compute = timed(robot, controller.compute)  # type: ignore[method-assign]
        controller.bid = timed(robot, controller.bid)  # type: ignore[method-assign]
    cpu0 = time.thread_time()
    summary = world.run().summary
    cpu = time.thread_time() - cpu0
    robots = sorted(world.host.controllers)
    ticks = sorted({tick for _, tick in costs})
    at = {tick: i for i, tick in enumerate(ticks)}
    index = {r: j for j, r in enumerate(robots)}
    work = np.zeros((len(ticks), len(robots)))
    for (robot, tick), c in costs.items():
        work[at[tick], index[robot]] = c
    return robots, work, cpu - float(work.sum()), summary


def balance(scenario) -> None:
    """Time every controller step and bid of an in-process run per robot and round (CPU time);
    print how the work would spread over 2 workers."""
    robots, work, engine, summary = time_work(scenario)
    index = {r: j for j, r in enumerate(robots)}
    total = float(work.sum())
    solving = (work > 2e-3).sum(axis=1)  # robots that solved or bid (> 2 ms) in the round

    def lockstep(shares: list[list[str]]) -> float:
        """Controller time of the run on 2 workers: every round waits for the slower one."""
        per_share = [work[:, [index[r] for r in share]].sum(axis=1) for share in shares]
        return float(np.maximum(*per_share).sum())

    fixed = shares_of(robots, greedy_sides(work.sum(axis=0)))
    splits = {
        "contiguous shares (what `--workers 2` uses)": split_robots(robots, 2),
        "interleaved shares (r01, r03, ... and r02, r04, ...)": [robots[0::2], robots[1::2]],
        # Dealt in turn, every other pass backwards: neighbours in id order (which start side
        # by side, start stations cycled) go to different workers.
        "snake deal (r01, r04, r05, r08, ... and r02, r03, r06, r07, ...)": [
            robots[0::4] + robots[3::4],
            robots[1::4] + robots[2::4],
        ],
        "greedy by each robot's total work (known beforehand)": fixed,
        "best fixed split found (hindsight)": best_fixed_split(work, robots, fixed[0]),
    }
    # No split can beat, in any round, half the round's work or its heaviest robot.
    best = float(np.maximum(work.sum(axis=1) / 2, work.max(axis=1)).sum())
    print(
        f"{len(robots)} robots, {summary['sim_time_s']:g} simulated s, "
        f"{summary['jobs']['completed']}/{summary['jobs']['released']} jobs delivered; "
        f"wall {summary['wall_time_s']:.1f} s; CPU: controllers {total:.1f} s, "
        f"engine {engine:.1f} s"
    )
    print(
        f"robots solving per round: median {np.median(solving):g}, mean {solving.mean():.2f}; "
        f"rounds with at most one: {np.mean(solving <= 1):.0%}"
    )
    heavy = sorted(zip(work.sum(axis=0), robots, strict=True), reverse=True)[:5]
    print("heaviest robots: " + ", ".join(f"{r} {c / total:.0%}" for c, r in heavy))
    # Pipelined, the engine steps while the workers compute: at best each run takes the longer
    # of the two (per round, which these totals can only bound).
    print(
        f"speed-up of 2 workers over 1 the lockstep allows (engine share {engine:.1f} s), "
        "strict / pipelined with the engine hidden:"
    )
    times = {label: lockstep(shares) for label, shares in splits.items()}
    # Robots moved between workers every 4 rounds, greedy by their work in the rounds before
    # (decayed by 0.8 a round): what moving them by their past load could buy.
    side, recent, moved = np.arange(len(robots)) >= len(robots) / 2, np.zeros(len(robots)), 0.0
    for k, row in enumerate(work):
        if k and k % 4 == 0:
            side = greedy_sides(recent)
        moved += max(row[side].sum(), row[~side].sum())
        recent = 0.8 * recent + row
    times["robots moved every 4 rounds by their past work"] = moved
    # Any worker computes any robot's step: each goes, in id order, to the worker free first.
    stolen = 0.0
    for row in work:
        free = [0.0, 0.0]
        for c in row:
            free[int(free[1] < free[0])] += c
        stolen += max(free)
    times["steps shared out within each round (id order)"] = stolen
    times["best split of every round"] = best
    for label, t in times.items():
        strict = (engine + total) / (engine + t)
        print(f"  {label}: {strict:.2f} / {max(engine, total) / max(engine, t):.2f}")
    # More workers than cores: the system shares the 2 cores among them, so a round lasts as
    # long as its busiest worker or half its work, whichever is longer (ideal time-sharing).
    for w in (3, 4, 8):
        per = [work[:, [index[r] for r in share]].sum(axis=1) for share in split_robots(robots, w)]
        shared = float(np.maximum(np.max(per, axis=0), work.sum(axis=1) / 2).sum())
        print(
            f"  {w} workers sharing 2 cores, contiguous: {(engine + total) / (engine + shared):.2f}"
        )


def shares_of(robots: list[str], side: np.ndarray) -> list[list[str]]:
    """The two workers' robots, from each robot's worker (False / True)."""
    return [[r for r, s in zip(robots, side, strict=True) if s == k] for k in (False, True)]


def greedy_sides(loads: np.ndarray) -> np.ndarray:
    """Each robot's worker (of 2, as False / True), heaviest `loads` first to the lighter one."""
    side = np.zeros(len(loads), dtype=bool)
    sums = [0.0, 0.0]
    for j in np.argsort(-loads, kind="stable"):
        side[j] = sums[1] < sums[0]
        sums[int(side[j])] += loads[j]
    return side


def best_fixed_split(work: np.ndarray, robots: list[str], start: list[str]) -> list[list[str]]:
    """A split of the robots (columns of `work`) over 2 workers that no single move of a robot
    or swap of two improves, judged by the lockstep's time (the slower worker of each round,
    summed): hindsight, about the most a fixed split could have bought in this run. A local
    search from `start` (the first worker's robots), so a local optimum, not proven best."""
    side = np.array([r not in start for r in robots])
    while True:
        a, b = work[:, ~side].sum(axis=1), work[:, side].sum(axis=1)
        now = np.maximum(a, b).sum()
        d = np.where(side, -work, work)  # moving robot k shifts d[:, k] from a to b
        moves = np.maximum(a[:, None] - d, b[:, None] + d).sum(axis=0)
        i, j = np.nonzero(side[:, None] != side[None, :])
        swap_d = d[:, i] + d[:, j]
        swaps = np.maximum(a[:, None] - swap_d, b[:, None] + swap_d).sum(axis=0)
        if moves.min() >= now - 1e-9 and (swaps.size == 0 or swaps.min() >= now - 1e-9):
            return shares_of(robots, side)
        if swaps.size and swaps.min() < moves.min():
            k = int(np.argmin(swaps))
            side[[i[k], j[k]]] = ~side[[i[k], j[k]]]
        else:
            side[int(np.argmin(moves))] ^= True


def closest_approach(world: World) -> tuple[float, str, str, float]:
    """The smallest centre distance minus the sum of radii of any two robots over the run, from
    the recorded trajectories alone: ``(gap, robot, robot, t)``; a negative gap is a contact.

    Between two samples each robot moves in a straight line (the position advances with the
    step's velocity), so their difference does too: each step's minimum is exact, not sampled.
    """
    ids = sorted(world.robots)
    arrays = [world.recorder.trajectories[r].arrays() for r in ids]
    n = min(len(t) for t, _, _ in arrays)
    t = arrays[0][0][:n]
    xy = np.stack([a[1][:n] for a in arrays])  # (robots, samples, 2)
    radius = np.array([world.robots[r].spec.radius for r in ids])
    best = (math.inf, "", "", math.nan)
    for i in range(len(ids) - 1):
        d = xy[i + 1 :] - xy[i]  # (others, samples, 2)
        a, b = d[:, :-1], d[:, 1:]
        step = b - a
        length2 = np.einsum("rsk,rsk->rs", step, step)
        with np.errstate(invalid="ignore", divide="ignore"):
            f = np.where(length2 > 0, -np.einsum("rsk,rsk->rs", a, step) / length2, 0.0)
        f = np.clip(f, 0.0, 1.0)
        gap = np.hypot(*np.moveaxis(a + f[..., None] * step, -1, 0))
        gap -= radius[i] + radius[i + 1 :, None]
        j, k = np.unravel_index(int(np.argmin(gap)), gap.shape)
        if gap[j, k] < best[0]:
            best = (float(gap[j, k]), ids[i], ids[i + 1 + j], float(t[k] + f[j, k] * (t[1] - t[0])))
    return best


#: What became of a deadlock event (`deadlock_outcomes`), in the order the sweep prints them.
FATES = ("reached", "progressed", "handed back", "none")


def short_of_home(world: World) -> tuple[int, float | None]:
    """Robots without a job, meant to return home, farther than the arrival tolerance from
    their home at the end of the run; and the time of the last delivery (None: none)."""
    tol = world.scenario.arrival_tolerance_m
    away = sum(
        1
        for r in world.robots.values()
        if r.return_home and r.job is None and math.hypot(r.x - r.home[0], r.y - r.home[1]) > tol
    )
    done = [e.t for e in world.recorder.events if e.event == "delivered"]
    return away, max(done) if done else None


def deadlock_outcomes(world: World, goals: dict[tuple[float, str], tuple[float, float]]) -> dict:
    """What became of each deadlock event: the blocked robot ``reached`` its goal (within the
    arrival tolerance, or arrived/delivered; heading home, it ends the run at its home, which
    may be another than at the event: `fleet.engine.homes`), ``progressed`` (got 0.25 m closer
    to it than at the event), had its job ``handed back``, or ``none`` by the end of the run;
    and the median time (s) from the event to progress."""
    tol = world.scenario.arrival_tolerance_m
    events = world.recorder.events
    out: dict[str, Any] = dict.fromkeys(FATES, 0)
    # The same, apart: robots with a job at the event, and robots heading home.
    out["with a job"] = dict.fromkeys(FATES, 0)
    out["heading home"] = dict.fromkeys(FATES, 0)
    delays = []
    for e in events:
        if e.event != "deadlock":
            continue
        goal = goals.get((e.t, e.robot))
        t, xy, _ = world.recorder.trajectories[e.robot].arrays()
        after = t >= e.t - 1e-9
        gap = np.hypot(*(xy[after] - np.asarray(goal)).T) if goal is not None else None
        later = [
            f
            for f in events
            if f.t >= e.t
            and f.robot == e.robot
            and f.job == e.job
            and f.event in ("arrived", "delivered", "handed_back", "failed")
        ]
        arrived = bool(later) and later[0].event in ("arrived", "delivered")
        if not e.job:  # heading home: home at the end, a traded home too
            home = world.robots[e.robot].home
            arrived = math.hypot(xy[-1, 0] - home[0], xy[-1, 1] - home[1]) <= tol
        kind = "none"
        if arrived or (gap is not None and np.any(gap <= tol)):
            kind = "reached"
        elif gap is not None and np.any(gap <= gap[0] - 0.25):
            kind = "progressed"
        elif later:
            kind = "handed back"
        out[kind] += 1
        out["with a job" if e.job else "heading home"][kind] += 1
        if gap is not None and np.any(gap <= gap[0] - 0.25):
            delays.append(float(t[after][np.argmax(gap <= gap[0] - 0.25)] - e.t))
    out["median_s_to_progress"] = float(np.median(delays)) if delays else None
    return out


def sweep(
    base,
    sizes: list[int],
    duration: float,
    per_robot_rate: float,
    out: Path | None = None,
    options: dict[str, Any] | None = None,
) -> None:
    """The MPC fleet at each size: contacts, fallbacks, deadlocks and jobs (issue 16), and its
    pace (issue 17): real-time factor on the wall clock and on this process's CPU time (the
    machine is shared: CPU time is what a run costs, the wall clock what it waited too), solve
    median / p95 (ms, wall), solves and ticks that followed the previous plan instead
    (``reuse_ticks``). `options` are MPC controller options; with `out`, each run's directory
    is written to ``out/robots<N>`` for `fleet replay`."""
    print(
        f"MPC fleet sweep on {base.map.name}: {duration:g} simulated s, "
        f"{per_robot_rate:g} jobs per robot-hour, sensing {base.sensing_radius_m:g} m, "
        f"deadlock after {base.deadlock_after_s} s, seed {base.seed}"
    )
    print(
        f"{'robots':>6} {'contacts':>8} {'closest m':>9} {'pair, t':>16} {'fallbacks':>9} "
        f"{'deadlocks':>9} {'reached/progr/handed/none':>25} {'jobs done/rel':>13} "
        f"{'wall s':>7}"
    )
    for n in sizes:
        sc = base.override(robots=n, controller="mpc", duration=duration)
        sc = replace(sc, jobs=replace(sc.jobs, rate_per_h=per_robot_rate * n))
        if options:
            merged = dict(sc.controller.options, **options)
            sc = replace(sc, controller=PluginChoice(sc.controller.name, merged))
        world = World(sc)
        goals: dict[tuple[float, str], tuple[float, float]] = {}
        record = world.recorder.event

        def event(t, kind, job, robot="", station="", record=record, world=world, goals=goals):
            if kind == "deadlock":  # where the blocked robot was heading then
                goals[(t, robot)] = world.robots[robot].goal
            record(t, kind, job, robot, station)

        world.recorder.event = event  # type: ignore[method-assign]
        cpu0 = time.process_time()
        s = world.run().summary
        cpu = time.process_time() - cpu0
        if out is not None:
            world.write(out / f"robots{n}")
        gap, a, b, t = closest_approach(world)
        fate = deadlock_outcomes(world, goals)
        d = world.recorder.stats.get("deadlocks", 0)
        fates = "/".join(str(fate[k]) for k in FATES)
        centres = gap + world.robots[a].spec.radius + world.robots[b].spec.radius
        print(
            f"{n:>6} {s['violations']['collision']:>8} {centres:>9.3f} "
            f"{f'{a}-{b} {t:.1f}':>16} {s['solver']['fallbacks']:>9} {d:>9} "
            f"{fates:>25} "
            f"{s['jobs']['completed']:>6}/{s['jobs']['released']:<6} {s['wall_time_s']:>7.1f}"
        )
        print(
            f"{'':>6} closest: centre distance (contact below the sum of the radii); "
            f"gap to contact {gap:+.3f} m; solver {s['solver']['termination']}; hand-backs "
            f"{s['jobs']['handed_back']}, failed {s['jobs']['failed']}; median "
            f"{fate['median_s_to_progress']} s from a deadlock to progress",
        )
        away, last = short_of_home(world)
        apart = ", ".join(
            f"{who} {'/'.join(str(fate[who][k]) for k in FATES)}"
            for who in ("with a job", "heading home")
        )
        print(
            f"{'':>6} deadlocks (reached/progr/handed/none): {apart}; {away} robots short "
            f"of home at the end; last delivery at "
            f"{'-' if last is None else f'{last:.1f} s'}"
        )
        assert world.host is not None
        reuses = sum(getattr(c, "reuses", 0) for c in world.host.controllers.values())
        sv = s["solver"]
        print(
            f"{'':>6} pace: RTF {duration / s['wall_time_s']:.3f} (wall), {duration / cpu:.3f} "
            f"(CPU {cpu:.1f} s); solves {sv['steps']}, median {sv['median_ms'] or 0:.2f} ms, "
            f"p95 {sv['p95_ms'] or 0:.2f} ms; plan reused {reuses}; digest {s['digest'][:12]}",
            flush=True,
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    # Counts and times are checked as `fleet run` checks them: a bad value is refused by name
    # before anything runs (a negative --duration was a traceback from the scenario loader).
    ap.add_argument(
        "--minutes", type=_positive_float, default=30.0, help="simulated minutes (MPC fleet)"
    )
    ap.add_argument("--robots", type=_positive_int, default=20)
    ap.add_argument("--workers", type=_non_negative_int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--baseline-robots", type=_positive_int, default=1000)
    ap.add_argument("--baseline-seconds", type=_positive_float, default=60.0)
    ap.add_argument("--skip-mpc", action="store_true")
    ap.add_argument("--skip-baseline", action="store_true", help="no follower fleet")
    ap.add_argument(
        "--lockstep",
        nargs="+",
        default=["strict"],
        choices=["strict", "pipelined"],
        help="MPC fleet: the [bus] lockstep modes to run",
    )
    ap.add_argument(
        "--threads",
        type=_positive_int,
        nargs="+",
        default=[1],
        help="MPC fleet: threads per agent host ([bus] threads) to run with",
    )
    ap.add_argument("--balance", action="store_true", help="only the work-balance analysis")
    ap.add_argument("--rate", type=_positive_float, help="jobs per hour (default: the scenario's)")
    ap.add_argument(
        "--sweep", type=_positive_int, nargs="+", metavar="N", help="MPC fleet sizes to sweep"
    )
    ap.add_argument(
        "--duration", type=_positive_float, default=120.0, help="simulated s per sweep run"
    )
    ap.add_argument(
        "--per-robot-rate", type=_positive_float, default=120.0, help="sweep: jobs/robot-hour"
    )
    ap.add_argument("--out", type=Path, help="sweep: write each run's directory under this")
    ap.add_argument(
        "--release-until",
        type=_positive_float,
        metavar="S",
        help="release jobs only for the first S s",
    )
    ap.add_argument(
        "--options", nargs="*", default=[], metavar="K=V", help="sweep: MPC options (TOML values)"
    )
    ap.add_argument(
        "--seed", type=int, default=None, help="the scenario's seed (default: the file's)"
    )
    args = ap.parse_args()

    base = load_scenario(REPO_ROOT / "scenarios" / "fleet.toml")
    if args.seed is not None:
        # One sweep is one sample of a chaotic system: a change's effect on fallbacks and
        # deadlocks is judged over seeds.
        base = replace(base, seed=args.seed)
    if args.rate is not None:
        base = replace(base, jobs=replace(base.jobs, rate_per_h=args.rate))
    if args.release_until is not None:
        base = replace(base, jobs=replace(base.jobs, release_until_s=args.release_until))
    if args.sweep:
        options = {
            k: tomllib.loads(f"v = {v}")["v"] for k, v in (o.split("=", 1) for o in args.options)
        }
        sweep(base, args.sweep, args.duration, args.per_robot_rate, args.out, options)
        return
    if args.balance:
        sc = base.override(robots=args.robots, controller="mpc", duration=args.minutes * 60.0)
        balance(with_lockstep(sc, args.lockstep[0]))
        return
    if not args.skip_mpc:
        sc = base.override(robots=args.robots, controller="mpc", duration=args.minutes * 60.0)
        print(
            f"MPC fleet: {args.robots} robots, {args.minutes:g} simulated min on "
            f"{sc.map.name}, auction, {sc.jobs.rate_per_h:g} jobs/h, "
            f"sensing {sc.sensing_radius_m:g} m"
        )
        print(
            f"{'lockstep':>9} {'workers':>7} {'threads':>7} {'setup s':>8} {'run s':>8} "
            f"{'RTF':>6} {'solve med ms':>12} {'jobs done':>9} {'collisions':>10} digest"
        )
        for mode in args.lockstep:
            walls: dict[tuple[int, int], float] = {}
            digests = set()
            for t in args.threads:
                for w in args.workers:
                    s, setup = run(with_lockstep(sc, mode, t), w)
                    wall = s["wall_time_s"]
                    walls[w, t] = wall
                    digests.add(s["digest"])
                    print(
                        f"{mode:>9} {w:>7} {t:>7} {setup:>8.1f} {wall:>8.1f} "
                        f"{s['sim_time_s'] / wall:>6.2f} {s['solver']['median_ms'] or 0:>12.2f} "
                        f"{s['jobs']['completed']:>9} {s['violations']['collision']:>10} "
                        f"{s['digest'][:12]}"
                    )
                    # What could tie a run to the wall clock: solves cut by their time limit
                    # (not "optimal"), rounds that timed out, agents lost.
                    print(
                        f"{'':>25} solver {s['solver']['termination']}, fallbacks "
                        f"{s['solver']['fallbacks']}, bus timeouts "
                        f"{s['engine'].get('bus_timeouts', 0)}, faults {s['faults']}",
                        flush=True,
                    )
            for t in args.threads:
                if (1, t) in walls and (2, t) in walls:
                    print(
                        f"{mode}, {t} thread(s): speed-up 2 workers vs 1: "
                        f"{walls[1, t] / walls[2, t]:.2f}"
                    )
                if (0, t) in walls and (2, t) in walls:
                    print(
                        f"{mode}, {t} thread(s): speed-up 2 workers vs 0: "
                        f"{walls[0, t] / walls[2, t]:.2f}"
                    )
                if t != 1:
                    for w in args.workers:
                        if (w, 1) in walls and (w, t) in walls:
                            print(
                                f"{mode}, {w} worker(s): speed-up {t} threads vs 1: "
                                f"{walls[w, 1] / walls[w, t]:.2f}"
                            )
            if (1, 1) in walls and len(walls) > 1:
                (w, t), fastest = min(walls.items(), key=lambda kv: kv[1])
                print(
                    f"{mode}: fastest, {w} worker(s) x {t} thread(s), vs 1 worker x 1 thread: "
                    f"{walls[1, 1] / fastest:.2f}"
                )
            print(f"{mode}: digests agree: {len(digests) == 1}")
    if args.skip_baseline:
        return

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
