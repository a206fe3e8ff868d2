"""Bus wire schema speed: encode and decode, another revision's schema against this tree's.

Loads ``fleet/bus/schema.py`` as it is at --ref (default ``main``, read with ``git show``) and
as it is in this tree, and times both in the same run, alternating them round by round:
`encode` and `decode` of an OBSERVE message with 1, 10 and 50 observations (each with 8
neighbours whose plans hold 10 samples, a goal, a job, two speed-cap pieces; two job
announcements) and of an ACT message with 1, 10 and 50 commands (each with a 20-sample plan and
a solve report; one bid per command). Numbers are random full-precision floats, as a run sends.

Prints the median microseconds per call over --rounds rounds (each about --round-ms long, the
garbage collector off as in timeit) and the ratio ref/this. Both decode the same frame (written
by --ref's encode); before timing, each must decode its own frames and the other's to the same
bodies, so the wire formats are checked to agree. Nothing is asserted about speed.

    python scripts/bench_bus.py [--ref main] [--rounds 15] [--round-ms 40]
"""

from __future__ import annotations

import argparse
import gc
import importlib.util
import random
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from types import ModuleType
from typing import Any

from fleet.bus import schema as this
from fleet.plugins import (
    Announcement,
    Bid,
    Command,
    ControlStatus,
    Neighbour,
    Observation,
    SolveReport,
    SolverOutcome,
)

REPO = Path(__file__).resolve().parents[1]
SIZES = (1, 10, 50)


def load_schema(ref: str) -> ModuleType:
    """``fleet/bus/schema.py`` at git revision `ref`, as a module of its own."""
    source = subprocess.run(
        ["git", "show", f"{ref}:fleet/bus/schema.py"],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    name = f"bench_bus_schema_{ref.replace('/', '_')}"
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader(name, loader=None))
    sys.modules[name] = module  # dataclasses look their module up while the class is made
    exec(compile(source, f"{ref}:fleet/bus/schema.py", "exec"), module.__dict__)
    return module


def observe_body(n: int, rng: random.Random) -> dict[str, Any]:
    def plan(t: float) -> tuple[tuple[float, float, float], ...]:
        x, y = rng.uniform(0, 40), rng.uniform(0, 20)
        return tuple(
            (t + 0.5 * k, x + rng.uniform(-1, 1), y + rng.uniform(-1, 1)) for k in range(10)
        )

    t = 308.25
    observations = []
    for i in range(n):
        neighbours = tuple(
            Neighbour(
                f"r{(i + k) % 64}",
                rng.uniform(0, 40),
                rng.uniform(0, 20),
                rng.uniform(-1, 1),
                rng.uniform(-1, 1),
                0.4,
                rng.randrange(100),
                plan(t),
            )
            for k in range(1, 9)
        )
        observations.append(
            Observation(
                f"r{i}",
                1233,
                t,
                rng.uniform(0, 40),
                rng.uniform(0, 20),
                rng.uniform(-1, 1),
                rng.uniform(-1, 1),
                goal=(rng.uniform(0, 40), rng.uniform(0, 20)),
                job=f"job-{i}",
                speed_cap=0.3,
                neighbours=neighbours,
                speed_caps=((t, t + 20.0, 0.3), (t + 20.0, t + 60.0, 0.5)),
                priority=i,
                blockers=(),
                queued=0,
            )
        )
    announcements = [
        Announcement(f"job-{100 + j}", rng.uniform(0, 40), rng.uniform(0, 20), 120.0, t, None)
        for j in range(2)
    ]
    return {"t": t, "observations": observations, "announcements": announcements}


def act_body(n: int, rng: random.Random) -> dict[str, Any]:
    t = 308.25
    commands = {
        f"r{i}": Command(
            rng.uniform(-0.5, 0.5),
            rng.uniform(-0.5, 0.5),
            ControlStatus.OK,
            tuple((t + 0.25 * k, rng.uniform(0, 40), rng.uniform(0, 20)) for k in range(20)),
            SolveReport(SolverOutcome.OPTIMAL, rng.uniform(0, 0.01), rng.uniform(0, 0.02)),
        )
        for i in range(n)
    }
    bids = [Bid("job-100", robot, rng.uniform(0, 600)) for robot in commands]
    return {"commands": commands, "bids": bids, "handbacks": []}


def per_call_us(fn: Callable[[], Any], calls: int) -> float:
    gc.disable()
    try:
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        return (time.perf_counter() - start) / calls * 1e6
    finally:
        gc.enable()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", default="main", help="git revision to compare with (default main)")
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--round-ms", type=float, default=40.0, help="about how long one round is")
    args = ap.parse_args()

    ref = load_schema(args.ref)
    rng = random.Random(7)
    cases = [("OBSERVE", n, observe_body(n, rng)) for n in SIZES]
    cases += [("ACT", n, act_body(n, rng)) for n in SIZES]
    print(f"median us per call over {args.rounds} alternating rounds; ref = {args.ref}")
    head = ("message", "items", "bytes", "op", "ref", "this", "ref/this")
    print("{:<8} {:>5} {:>7}  {:<6} {:>9} {:>9} {:>9}".format(*head))
    for kind_name, n, body in cases:
        frames = [m.encode(m.MessageKind[kind_name], "exchange", 1233, body) for m in (ref, this)]
        for written in frames:
            for m in (ref, this):
                assert m.decode(written).body == body, (m.__name__, kind_name, n)
        frame = frames[0]
        ops = {
            "encode": [
                partial(m.encode, m.MessageKind[kind_name], "exchange", 1233, body)
                for m in (ref, this)
            ],
            "decode": [partial(m.decode, frame) for m in (ref, this)],
        }
        for op, fns in ops.items():
            # As many calls per round as take about --round-ms on the reference.
            calls = max(1, round(args.round_ms / 1e3 / (per_call_us(fns[0], 3) / 1e6)))
            times: list[list[float]] = [[], []]
            for _ in range(args.rounds):
                for side, fn in enumerate(fns):
                    times[side].append(per_call_us(fn, calls))
            a, b = (statistics.median(t) for t in times)
            print(
                f"{kind_name:<8} {n:>5} {len(frame):>7}  {op:<6} {a:>9.1f} {b:>9.1f} {a / b:>9.2f}"
            )


if __name__ == "__main__":
    main()
