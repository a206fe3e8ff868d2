"""HiGHS work per MPC solve: how many solves end at a limit, and the spread of the work.

Runs the paper's case 3 (`scenarios/paper_case3_s1.toml`, `_s2.toml`) and the MPC fleet on
`scenarios/fleet.toml` (``--robots`` sizes, ``--duration`` simulated s, jobs at 120 per
robot-hour as in ``bench_fleet.py --sweep``) in this process and records, for every MPC step
solve (the direct interface's MILPs), how HiGHS ended (model status) and its work: branch-and-
bound nodes (``mip_node_count``) and simplex iterations (``simplex_iteration_count``), plus the
wall and CPU time of the run. Printed per run: solves, how many ended at the time limit or a
work limit, the spread (median, p95, p99, p99.9, max) of nodes, iterations and wall time, the
solver summary's termination counts, its median / p95 and the digest. Nothing is asserted:
the figures go in docs/mpc.md ("Deterministic stopping").

    python scripts/bench_mpc_work.py [--case3] [--robots 20 40] [--duration 60]
        [--options time_limit_s=1.0]
"""

from __future__ import annotations

import argparse
import time
import tomllib
from collections import Counter
from dataclasses import replace

import numpy as np

import fleet_plugins.mpc.model as mpc_model
from fleet.engine import World
from fleet.scenario import REPO_ROOT, PluginChoice, load_scenario

#: One row per MILP solve: (model status, nodes, simplex iterations, wall ms, CPU ms).
SOLVES: list[tuple[str, int, int, float, float]] = []


def _recorded(run_outcome):
    def run(h, what):
        w0, c0 = time.perf_counter(), time.process_time()
        try:
            return run_outcome(h, what)
        finally:
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            info = h.getInfo()
            status = h.modelStatusToString(h.getModelStatus())
            SOLVES.append(
                (
                    status,
                    int(info.mip_node_count),
                    int(info.simplex_iteration_count),
                    wall * 1e3,
                    cpu * 1e3,
                )
            )

    return run


def _spread(values: list[float]) -> str:
    a = np.asarray(values, dtype=float)
    q = np.percentile(a, [50, 95, 99, 99.9])
    return (
        f"median {q[0]:g}, p95 {q[1]:g}, p99 {q[2]:g}, p99.9 {q[3]:.4g}, max {a.max():g}"
        if len(a)
        else "-"
    )


def report(label: str, world: World, summary: dict, wall_s: float) -> None:
    rows = SOLVES[:]
    status = Counter(r[0] for r in rows)
    sv = summary["solver"]
    print(f"== {label}: {len(rows)} MILP solves, wall {wall_s:.1f} s", flush=False)
    print(f"   HiGHS status: {dict(status)}")
    print(f"   nodes: {_spread([r[1] for r in rows])}")
    print(f"   simplex iterations: {_spread([r[2] for r in rows])}")
    print(f"   wall ms: {_spread([round(r[3], 3) for r in rows])}")
    print(f"   CPU ms: {_spread([round(r[4], 3) for r in rows])}")
    stopped = [r for r in rows if r[0] != "Optimal" and "nfeasible" not in r[0]]
    if stopped:
        seen = [(r[0], r[1], r[2], round(r[3]), round(r[4])) for r in stopped]
        print(f"   stopped at a limit (status, nodes, iterations, wall ms, CPU ms): {seen}")
    print(
        f"   summary: termination {sv['termination']}, fallbacks {sv['fallbacks']}, "
        f"time_limit_hits {sv.get('time_limit_hits', '-')}, median {sv['median_ms']} ms, "
        f"p95 {sv['p95_ms']} ms; digest {summary['digest'][:16]}",
        flush=True,
    )


def run(label: str, sc) -> None:
    SOLVES.clear()
    world = World(sc)
    t0 = time.perf_counter()
    summary = world.run().summary
    report(label, world, summary, time.perf_counter() - t0)


def _with_options(sc, options: dict):
    if not options:
        return sc
    merged = dict(sc.controller.options, **options)
    return replace(sc, controller=PluginChoice(sc.controller.name, merged))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case3", action="store_true", help="case 3 s1 and s2")
    ap.add_argument("--robots", type=int, nargs="*", default=[], help="MPC fleet sizes")
    ap.add_argument("--duration", type=float, default=60.0, help="simulated s per fleet run")
    ap.add_argument("--options", nargs="*", default=[], metavar="K=V", help="MPC options (TOML)")
    args = ap.parse_args()
    options = {k: v for o in args.options for k, v in tomllib.loads(o).items()}
    mpc_model.run_outcome = _recorded(mpc_model.run_outcome)
    if args.case3:
        for name in ("paper_case3_s1", "paper_case3_s2"):
            sc = load_scenario(REPO_ROOT / "scenarios" / f"{name}.toml")
            run(name, _with_options(sc, options))
    base = load_scenario(REPO_ROOT / "scenarios" / "fleet.toml")
    for n in args.robots:
        sc = base.override(robots=n, controller="mpc", duration=args.duration)
        sc = replace(sc, jobs=replace(sc.jobs, rate_per_h=120.0 * n))
        run(f"fleet {n} robots, {args.duration:g} s", _with_options(sc, options))


if __name__ == "__main__":
    main()
