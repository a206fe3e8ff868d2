"""MPC solve times on case study 3: the speed that decides whether fleet studies are practical.

Runs `scenarios/paper_case3_s1.toml` and `_s2.toml` (one robot, N = 25, dt = 1 s) through the
engine, --repeats times per interface, and prints per scenario and interface, pooled over all
solves: HiGHS's own solve time (median, p95, max), the whole controller step (median), the
modelling layer's overhead (sum of step times / sum of solve times, and the median of the
per-step ratios), binaries switched on per solve, fallbacks, the arrival time and violations;
and on a line of its own HiGHS's CPU time per solve (this process's time, which a shared
machine's load does not inflate as it does the wall clock).

Interfaces: ``direct`` (the default: bounds written into the persistent HiGHS object by index)
and ``pyomo`` (mutable Params through Pyomo's persistent update). Nothing here is asserted: the
figures go in notes and the README. Targets (issue 3, 2-core machine): median <= 20 ms,
p95 <= 60 ms, max <= 250 ms, overhead <= 1.5, no fallbacks.

    python scripts/bench_mpc.py [--repeats 3] [--interfaces direct pyomo] [--cost l1 quadratic]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

import fleet_plugins.mpc.model as mpc_model
from fleet.engine import World
from fleet.scenario import REPO_ROOT, PluginChoice, load_scenario

#: HiGHS's CPU time (this process's, ms) per MPC solve: on a shared machine the wall clock also
#: counts the waits for a core, CPU time only the work (issue 17).
CPU_MS: list[float] = []


def _timed_run_outcome(run_outcome):
    def timed(h, what):
        c0 = time.process_time()
        try:
            return run_outcome(h, what)
        finally:
            CPU_MS.append((time.process_time() - c0) * 1e3)

    return timed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--interfaces", nargs="+", default=["direct", "pyomo"])
    ap.add_argument("--scenarios", nargs="+", default=["paper_case3_s1", "paper_case3_s2"])
    ap.add_argument("--options", nargs="*", default=[], help="extra controller options k=v")
    args = ap.parse_args()
    extra = dict(_option(o) for o in args.options)
    mpc_model.run_outcome = _timed_run_outcome(mpc_model.run_outcome)

    print(
        f"{'scenario':<16} {'interface':<9} {'solves':>6} {'HiGHS med':>9} {'p95':>7} "
        f"{'max':>7} {'step med':>8} {'ratio sum':>9} {'ratio med':>9} {'bin med':>7} "
        f"{'bin max':>7} {'fallbk':>6} {'arrival':>7} {'viol':>4}"
    )
    for name in args.scenarios:
        base = load_scenario(REPO_ROOT / "scenarios" / f"{name}.toml")
        for interface in args.interfaces:
            options = dict(base.controller.options, interface=interface, **extra)
            sc = replace(base, controller=PluginChoice(base.controller.name, options))
            solver, step, binaries, fallbacks, arrivals, violations = [], [], [], 0, set(), 0
            CPU_MS.clear()
            for _ in range(args.repeats):
                world = World(sc)
                result = world.run()
                solver += [s.solver_s * 1e3 for s in world.solves]
                step += [s.step_s * 1e3 for s in world.solves]
                for c in world.host.controllers.values():
                    binaries += getattr(c, "binaries", [])
                s = result.summary
                fallbacks += s["solver"]["fallbacks"]
                arrivals.add(s["arrivals"]["r01"])
                violations += sum(s["violations"].values())
            sv, st = np.array(solver), np.array(step)
            arrival = "/".join(f"{a:g}" for a in sorted(arrivals, key=lambda a: a or 0))
            print(
                f"{name:<16} {interface:<9} {len(sv):>6} {np.median(sv):>9.1f} "
                f"{np.percentile(sv, 95):>7.1f} {sv.max():>7.1f} {np.median(st):>8.1f} "
                f"{st.sum() / sv.sum():>9.2f} {np.median(st / sv):>9.2f} "
                f"{np.median(binaries):>7.0f} {max(binaries):>7d} {fallbacks:>6d} "
                f"{arrival:>7} {violations:>4d}"
            )
            cpu = np.array(CPU_MS)
            if len(cpu):  # the pyomo interface solves through Pyomo, untimed here
                print(
                    f"{'':<16} {'':<9} HiGHS CPU time (process): median {np.median(cpu):.1f}, "
                    f"p95 {np.percentile(cpu, 95):.1f}, max {cpu.max():.1f} ms"
                )


def _option(text: str) -> tuple[str, object]:
    key, _, value = text.partition("=")
    for cast in (int, float):
        try:
            return key, cast(value)
        except ValueError:
            pass
    if value in ("true", "false"):
        return key, value == "true"
    return key, value


if __name__ == "__main__":
    main()
