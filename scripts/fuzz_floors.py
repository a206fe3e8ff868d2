"""Our own fuzz of floors and fleets (issue 16, item 4): random floors, judged from the map alone.

Each case is a folder with ``floor.toml`` and ``scen.toml`` (like ``tests/cases/*``), drawn from
a master seed and the case's index, so every case is reproducible:

- a hall (a rectangle, 20-40 m by 15-30 m, sometimes rotated) with rotated and concave
  obstacles (rectangles, L, T, U and plus shapes, irregular outlines), walls with doors just
  wide enough for a robot (``2 * max(radius, clearance)`` plus a little), speed zones (polygons
  and rings ``around`` obstacles and zones, slower than the default), stations in free space,
  some a few centimetres from a wall or a machine;
- a fleet of 1-8 robots (the MPC, one case in four, gets shorter runs), a
  random control period in 0.1-1.0 s, the greedy or the auction dispatcher, Poisson jobs or
  scripted trips (some ``via`` stations, some printing under speed caps).

Each case is run with the engine (`fleet.engine.World`) and judged by an oracle written from
the map file alone (tomllib and shapely; neither `fleet.floor` nor the engine's safety checker)
and the run's record (samples, events, print caps). Finding kinds:

``obstacle``      a robot's disc overlaps an obstacle or leaves the hall (at a sample or on
                  the straight segment to the next; the engine's model moves p += dt * v)
``clearance``     no contact, but the centre came closer than ``floor.clearance`` to an
                  obstacle or the wall (the map promises that clearance)
``zone_speed``    a step entering a speed zone (or the zone-free floor) faster, on some axis,
                  than its limit
``robot_speed``   faster, on some axis, than the robot's own v_max
``print_speed``   faster than a print cap in force (the run's caps.csv rows)
``accel``         a velocity change over a step larger than a_max * dt on some axis
``contact``       two robots closer than the sum of their radii (at samples, or between two
                  common samples where both move on straight lines)
``stuck``         a robot with a job it has not reached stays within 0.5 m for the last
                  `STUCK_S` seconds of the run
``stuck_home``    an idle robot away from home (return_home; any robot's start spot, as
                  idle robots trade homes) stays put the same way, or stays within
                  `WANDER_M` and gets no nearer home
``job_waiting``   a job stays unassigned for `WAIT_S` seconds while a robot is idle
``job_not_done``  a job released `DONE_GRACE_S` seconds or more before the end is neither
                  delivered nor failed with a reason, and is still not in a longer run of the
                  same case (`confirm_duration`; or it failed without a reason)
``job_late``      (informational: the case does not fail) such a job was not done at the end,
                  but the longer run delivers it or fails it with a reason: slow, not stuck
``home_late``     (informational) a robot found ``stuck_home`` at the end that gets home in
                  the longer run: held up (a crowd between it and home), not stuck for good
``controller_error`` a robot's controller raised while it had somewhere to go (the agent
                  brakes the robot and counts it: summary.json's ``goal_errors``)
``run_error``     the floor and scenario loaded, but the run raised a FleetError
``crash``         any other exception (its traceback is saved)

A case with a ``job_not_done`` finding (whatever else it found) is run again, the same floor,
scenario and seed, for `confirm_duration` seconds; only the jobs not done in the first run are
judged there (jobs released after the first run's end, and the longer run's other findings, do
not count): each ended one becomes ``job_late``, the rest stay ``job_not_done``. A
``stuck_home`` finding is judged there the same way: a robot that gets home after the first
run's end becomes ``home_late``. The first part of the longer run is the first run (the engine's
run does not depend on its duration up to the end), so it adds time only, and only for these
cases.

A map or scenario the loader refuses with a `FleetError` is counted as *refused* (allowed by
the issue), with the first line of its message.

Prints counts per finding kind, the engine's own counts (violations, deadlocks, fallbacks,
stuck robots) side by side, the median wall time per floor, and saves each failing case under
--out as a folder (floor.toml, scen.toml, findings.txt with the command that reruns it);
--out/results.jsonl gets one line per case as it finishes, appended to the rows already there
(a run resumed with --first adds to its file; the start line says how many rows were there).

    python scripts/fuzz_floors.py --floors 1000 --seed 1 --workers 2 --out fuzz-out
    python scripts/fuzz_floors.py --controller mpc --floors 50
    python scripts/fuzz_floors.py --case fuzz-out/s1-0042      # rerun and judge one folder
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import random
import re
import shutil
import statistics
import sys
import tempfile
import time
import tomllib
import traceback
from collections import Counter, defaultdict
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import Point, Polygon, box
from shapely.geometry.base import BaseGeometry
from shapely.ops import nearest_points, unary_union

REPO = Path(__file__).resolve().parents[1]
#: One line per case in --out, as each finishes (appended to: a resumed run adds to it).
RESULTS = "results.jsonl"

#: Lengths (m) and speeds (m/s) within these of a limit are rounding, not findings.
LENGTH_TOL = 1e-6
SPEED_TOL = 1e-6
#: Robots in an MPC case unless `--fleet` says otherwise, drawn uniformly (from the case's
#: own stream, as `--fleet`'s).
MPC_FLEET = (1, 8)
#: A robot that has somewhere to go and stays within `STUCK_RADIUS_M` for the last `STUCK_S`
#: seconds is stuck for good (judged only in runs at least `LIVENESS_MIN_S` long).
STUCK_S = 90.0
STUCK_RADIUS_M = 0.5
#: An idle robot that stays within this (m) of where it was `STUCK_S` before the end, more than
#: `STUCK_RADIUS_M` from home all along and no nearer it than then (by `STUCK_RADIUS_M`), is
#: stuck too: one drove back and forth over 1.3 m, 4.3 m from home, for the last 90 s of a run.
WANDER_M = 3.0
LIVENESS_MIN_S = 180.0
#: A job unassigned this long while some robot is idle all along is waiting beside it.
WAIT_S = 60.0
#: Every job released this long before the end must be delivered or failed.
DONE_GRACE_S = 150.0
#: A job not done at the end is judged again in a run this much longer (`confirm_duration`):
#: three times as long, and at least 10 minutes more, so a job that is only slow (a long via
#: trip at a coarse period, a long print, a queue at one station) ends there, while one that
#: waits on something that never changes still does not.
CONFIRM_FACTOR = 3.0
CONFIRM_EXTRA_S = 600.0
#: Kinds that are reported and counted but do not make a case fail.
INFO_KINDS = frozenset({"job_late", "home_late"})
#: The engine's own safety counts (summary.json ``violations``).
SAFETY_KEYS = ("collision", "obstacle", "speed_zone", "print_speed")
#: Finding kinds in the order the table prints them.
KINDS = (
    "obstacle",
    "clearance",
    "zone_speed",
    "robot_speed",
    "print_speed",
    "accel",
    "contact",
    "stuck",
    "stuck_home",
    "home_late",
    "job_waiting",
    "job_not_done",
    "job_late",
    "controller_error",
    "run_error",
    "crash",
)

# --- TOML out ----------------------------------------------------------------------------------


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(round(v, 4)) if math.isfinite(v) else "nan"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{k} = {_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"no TOML for {v!r}")


def dump_toml(doc: Mapping[str, Any]) -> str:
    """`doc` as TOML: tables of scalars, lists and inline tables (dicts); a list of dicts is an
    array of tables (``[[jobs.scripted]]``), at any depth."""
    lines: list[str] = []

    def table(prefix: str, body: Mapping[str, Any], array: bool) -> None:
        lines.append(f"[[{prefix}]]" if array else f"[{prefix}]")
        subs = []
        for k, v in body.items():
            if isinstance(v, list) and v and all(isinstance(x, Mapping) for x in v):
                subs.append((k, v))
            else:
                lines.append(f"{k} = {_value(v)}")
        lines.append("")
        for k, v in subs:
            for item in v:
                table(f"{prefix}.{k}", item, True)

    for name, body in doc.items():
        if isinstance(body, list):
            for item in body:
                table(name, item, True)
        else:
            table(name, body, False)
    return "\n".join(lines)


# --- the generator -----------------------------------------------------------------------------

SHAPES = ("rect", "rect", "L", "T", "U", "plus", "irregular", "triangle")


def _shape(rng: random.Random, kind: str, size: float) -> Polygon:
    """An obstacle outline of `kind`, about `size` metres across, centred on the origin."""
    a, b = size * rng.uniform(0.4, 1.0), size * rng.uniform(0.4, 1.0)
    t = size * rng.uniform(0.2, 0.4)  # arm thickness of the concave shapes
    if kind == "rect":
        pts = [(0, 0), (a, 0), (a, b), (0, b)]
    elif kind == "L":
        pts = [(0, 0), (a, 0), (a, t), (t, t), (t, b), (0, b)]
    elif kind == "T":
        m = a / 2
        pts = [(0, b - t), (0, b), (a, b), (a, b - t), (m + t / 2, b - t), (m + t / 2, 0)]
        pts += [(m - t / 2, 0), (m - t / 2, b - t)]
    elif kind == "U":
        pts = [(0, 0), (a, 0), (a, b), (a - t, b), (a - t, t), (t, t), (t, b), (0, b)]
    elif kind == "plus":
        h = t / 2
        pts = [(-h, -b / 2), (h, -b / 2), (h, -h), (a / 2, -h), (a / 2, h), (h, h), (h, b / 2)]
        pts += [(-h, b / 2), (-h, h), (-a / 2, h), (-a / 2, -h), (-h, -h)]
    elif kind == "triangle":
        pts = [(0, 0), (a, rng.uniform(-0.3, 0.3) * b), (rng.uniform(0.2, 0.8) * a, b)]
    else:  # irregular: a star-shaped polygon, may be concave
        n = rng.randrange(5, 10)
        angles = sorted(rng.uniform(0, 2 * math.pi) for _ in range(n))
        pts = [
            (
                math.cos(q) * size / 2 * rng.uniform(0.5, 1.0),
                math.sin(q) * size / 2 * rng.uniform(0.5, 1.0),
            )
            for q in angles
        ]
    poly = Polygon(pts)
    c = poly.centroid
    return affinity.translate(poly, -c.x, -c.y)


def _coords(poly: Polygon) -> list[list[float]]:
    return [[round(x, 4), round(y, 4)] for x, y in list(poly.exterior.coords)[:-1]]


def _rounded(poly: Polygon) -> Polygon:
    """`poly` with its vertices rounded as the map file writes them."""
    return Polygon([(round(x, 4), round(y, 4)) for x, y in poly.exterior.coords])


def _mitre(geom: BaseGeometry, d: float) -> BaseGeometry:
    """The map format's growth: mitred corners, mitre limit 5 (maps/README.md)."""
    return geom if d == 0 else geom.buffer(d, join_style="mitre", mitre_limit=5.0)


@dataclass
class Case:
    """One generated case: its name, the two files' documents and what was drawn."""

    name: str
    floor: dict[str, Any]
    scen: dict[str, Any]
    controller: str
    note: str = ""

    def write(self, folder: Path) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "floor.toml").write_text(dump_toml(self.floor), encoding="utf-8")
        (folder / "scen.toml").write_text(dump_toml(self.scen), encoding="utf-8")
        return folder


def generate_case(
    seed: int,
    index: int,
    controller: str = "both",
    quick: bool = False,
    mpc_options: dict[str, Any] | None = None,
    fleet: tuple[int, int] | None = None,
) -> Case:
    """Case `index` of master seed `seed` (the same pair always gives the same case).

    `quick`: a small fleet (1-3 robots, the MPC 1-2) and a short run (the test suite's sample;
    other draws as usual, but the stream differs from the full cases'). `mpc_options`: MPC
    controller options written into an MPC case's scenario (no draw depends on them, so the
    floors and fleets are the same with and without). `fleet`: the number of robots is drawn
    from this range (inclusive) instead, from a stream of its own, so the floor, the
    controller and the robots' kind are the same case's (the draws after it, the jobs among
    them, depend on the count).
    """
    rng = random.Random(f"fuzz-floors/{seed}/{index}" + ("/quick" if quick else ""))
    if controller == "both":
        controller = "mpc" if rng.random() < 0.25 else "follower"
    mpc = controller == "mpc"

    radius = round(rng.uniform(0.25, 0.5), 3)
    r = rng.random()
    clearance = radius if r < 0.6 else round(radius + rng.uniform(0.0, 0.2), 3)
    reach = max(radius, clearance)

    w, h = round(rng.uniform(20, 40), 2), round(rng.uniform(15, 30), 2)
    hall = box(0, 0, w, h)
    angle = rng.choice([0.0, 0.0, rng.uniform(-60, 60)])
    origin = (round(rng.uniform(-50, 50), 2), round(rng.uniform(-50, 50), 2))

    def place(g: BaseGeometry) -> BaseGeometry:
        g = affinity.rotate(g, angle, origin=(0, 0)) if angle else g
        return affinity.translate(g, *origin)

    floor: dict[str, Any] = {
        "floor": {
            "name": f"fuzz floor {seed}-{index}",
            "description": f"{w} x {h} m hall rotated {angle:.1f} deg",
            "default_v_max": round(rng.uniform(0.8, 1.5), 2),
            "clearance": clearance,
        }
    }
    if angle:
        floor["floor"]["boundary"] = _coords(place(hall))
    else:
        floor["floor"]["rect"] = [origin[0], origin[1], origin[0] + w, origin[1] + h]

    # Obstacles, in hall coordinates (placed, i.e. rotated and moved, when written).
    obstacles: list[tuple[str, Polygon]] = []
    inner = hall.buffer(-0.05, join_style="mitre")
    for i in range(rng.randrange(1, 8)):
        kind = rng.choice(SHAPES)
        poly = _shape(rng, kind, rng.uniform(1.5, 6.0))
        poly = affinity.rotate(poly, rng.choice([0.0, 90.0, rng.uniform(0, 360)]), origin=(0, 0))
        poly = affinity.translate(poly, rng.uniform(2, w - 2), rng.uniform(2, h - 2))
        if not inner.contains(poly) or not poly.is_valid:
            continue
        obstacles.append((f"m{i:02d}_{kind}", poly))
    # Walls with doors just wide enough: narrow passages.
    for j in range(rng.choice([0, 0, 1, 1, 2])):
        door = 2 * reach + rng.uniform(0.05, 0.5)
        thick = rng.uniform(0.2, 0.6)
        e = 0.01  # off the hall's walls by a rounding's worth: too narrow for any robot
        if rng.random() < 0.5:  # across x
            x = rng.uniform(0.3, 0.7) * w
            d0 = rng.uniform(1.0, h - door - 1.0)
            parts = [box(x, e, x + thick, d0), box(x, d0 + door, x + thick, h - e)]
        else:
            y = rng.uniform(0.3, 0.7) * h
            d0 = rng.uniform(1.0, w - door - 1.0)
            parts = [box(e, y, d0, y + thick), box(d0 + door, y, w - e, y + thick)]
        obstacles += [(f"wall{j}_{k}", p) for k, p in enumerate(parts)]
    # A pair of machines with a narrow gap between them.
    if rng.random() < 0.4:
        gap = 2 * reach + rng.uniform(0.05, 0.4)
        a_len, b_len = rng.uniform(2, 6), rng.uniform(1, 3)
        pair = [box(0, 0, a_len, b_len), box(0, b_len + gap, a_len, 2 * b_len + gap)]
        rot = rng.uniform(0, 180)
        cx, cy = rng.uniform(4, w - 4), rng.uniform(4, h - 4)
        pair = [
            affinity.translate(affinity.rotate(p, rot, origin=(a_len / 2, b_len + gap / 2)), cx, cy)
            for p in pair
        ]
        if all(inner.contains(p) for p in pair):
            obstacles += [("gap_a", pair[0]), ("gap_b", pair[1])]
    obstacles = [(n, _rounded(place(p))) for n, p in obstacles]
    hall_placed = _rounded(place(hall))
    floor["obstacles"] = [{"name": n, "polygon": _coords(p)} for n, p in obstacles]

    # Speed zones: polygons, and buffers/rings around obstacles.
    zones = []
    for i in range(rng.randrange(0, 4)):
        z = _shape(rng, rng.choice(["rect", "triangle", "irregular", "L"]), rng.uniform(3, 10))
        z = affinity.rotate(z, rng.uniform(0, 360), origin=(0, 0))
        z = affinity.translate(z, rng.uniform(0, w), rng.uniform(0, h))
        if not z.is_valid:
            continue
        z = place(z).intersection(hall_placed.buffer(-0.01, join_style="mitre"))
        if not isinstance(z, Polygon) or z.area < 1.0:
            continue
        z = _rounded(z.simplify(0.01))
        if not z.is_valid or not hall_placed.contains(z):
            continue
        zones.append(
            {"name": f"z{i}", "polygon": _coords(z), "v_max": round(rng.uniform(0.15, 0.8), 2)}
        )
    machines = [n for n, _ in obstacles if n[0] == "m"]
    for n in rng.sample(machines, min(len(machines), rng.randrange(0, 3))):
        v = round(rng.uniform(0.2, 0.6), 2)
        zones.append(
            {"name": f"{n}_buf", "around": n, "margin": round(rng.uniform(0.5, 2.0), 2), "v_max": v}
        )
        if rng.random() < 0.5:
            zones.append(
                {
                    "name": f"{n}_ring",
                    "around": f"{n}_buf",
                    "margin": round(rng.uniform(0.5, 2.0), 2),
                    "v_max": round(min(v + rng.uniform(0.1, 0.4), 1.0), 2),
                }
            )
    if zones:
        floor["zones"] = zones

    # Stations: in the largest piece of free space (grown as the map format grows).
    free = _mitre(hall_placed, -clearance).difference(
        unary_union([_mitre(p, clearance) for _, p in obstacles]) if obstacles else Polygon()
    )
    pieces = list(getattr(free, "geoms", [free]))
    main = max(pieces, key=lambda g: g.area) if pieces and not free.is_empty else None
    stations: list[tuple[str, float, float, str]] = []
    if main is not None:
        roomy = main.buffer(-(2 * radius + 0.3))  # room for robots round a station
        near = main.buffer(-0.02)
        n_st = rng.randrange(3, 9)
        depots = rng.randrange(1, 4)
        tries = 0
        while len(stations) < n_st and tries < 400:
            tries += 1
            wall = rng.random() < 0.3 and len(stations) >= depots
            target = near if wall else roomy
            if target.is_empty:
                continue
            if wall:
                rings = [main.exterior, *main.interiors]
                ring = rng.choice(rings)
                p = ring.interpolate(rng.uniform(0, ring.length))
                q = nearest_points(target, p)[0]
                x, y = q.x, q.y
            else:
                x0, y0, x1, y1 = target.bounds
                x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
                if not target.contains(Point(x, y)):
                    continue
            x, y = round(x, 4), round(y, 4)
            if any(math.dist((x, y), (sx, sy)) < 2 * radius + 1.0 for _, sx, sy, _ in stations):
                continue
            kind = "depot" if len(stations) < depots else "delivery"
            stations.append((f"st{len(stations)}", x, y, kind))
    if len(stations) < 2:  # an unusable floor: the loader or the placement refuses it
        stations = [("st0", *origin, "depot"), ("st1", origin[0] + 1, origin[1] + 1, "delivery")]
    if all(k == "depot" for *_, k in stations):  # every floor has somewhere to deliver to
        stations[-1] = (*stations[-1][:3], "delivery")
    floor["stations"] = [{"name": n, "at": [x, y], "kind": k} for n, x, y, k in stations]
    names = [n for n, *_ in stations]
    depots_ = [n for n, *_, k in stations if k == "depot"]
    deliveries = [n for n, *_, k in stations if k != "depot"] or names

    # The fleet and its jobs.
    count = rng.randrange(1, 4) if mpc else rng.choice([1, 2, 2, 3, 3, 4, 4, 5, 6, 7, 8])
    period = rng.choice([0.1, 0.2, 0.25, 0.25, 0.5, 1.0, round(rng.uniform(0.1, 1.0), 3)])
    if mpc:
        period = max(period, 0.2)
        duration = rng.choice([90, 120, 180, 200])
    else:
        duration = rng.choice([240, 300, 400, 600])
    if quick:
        count = rng.randrange(1, 3) if mpc else rng.randrange(1, 4)
        period = max(period, 0.25)
        duration = 60 if mpc else 180
    if fleet is None and mpc and not quick:
        # Issue 16 asks 1-8 robots of either controller (the draw above gave the MPC 1-3; it
        # stays, so the draws after it, and the floors, are what they were).
        fleet = MPC_FLEET
    if fleet is not None:
        count = random.Random(f"fuzz-floors/{seed}/{index}/fleet").randint(*fleet)
    scen: dict[str, Any] = {
        "scenario": {
            "name": f"fuzz-{seed}-{index}",
            "map": "floor.toml",
            "duration_s": duration,
            "seed": rng.randrange(1000),
            "arrival_tolerance_m": 0.05,
            "sensing_radius_m": round(rng.uniform(3.0, 10.0), 1),
            "deadlock_after_s": rng.choice([10, 20, 30]),
        },
        "robots": {
            "count": count,
            "start": rng.sample(depots_, rng.randrange(1, len(depots_) + 1)),
            "v_max": round(rng.uniform(0.5, 1.5), 2),
            "a_max": round(rng.uniform(0.3, 2.0), 2),
            "radius": radius,
            "period_s": period,
            "return_home": rng.random() < 0.7,
        },
        "controller": {"name": controller}
        | ({"options": dict(mpc_options)} if mpc and mpc_options else {}),
        "dispatcher": {"name": rng.choice(["greedy", "greedy", "auction"])},
    }
    printing = rng.random() < 0.3
    poisson = rng.random() < 0.4 and not quick  # quick runs are too short for Poisson jobs
    if poisson:
        scen["jobs"] = {
            "mode": "poisson",
            "rate_per_h": round(count * rng.uniform(5, 20), 1),
            "stations": rng.sample(deliveries, rng.randrange(1, len(deliveries) + 1)),
        }
    else:
        jobs = []
        for _ in range(rng.randrange(1, count + 2) if quick else rng.randrange(1, 2 * count + 3)):
            job: dict[str, Any] = {
                "at_s": round(rng.uniform(0, 10.0 if quick else duration * 0.4), 1),
                "station": rng.choice(deliveries),
            }
            if rng.random() < 0.3:
                others = [n for n in names if n != job["station"]]
                job["via"] = rng.sample(others, min(len(others), rng.randrange(1, 3)))
            if printing and rng.random() < 0.6:
                start, tasks = 0.0, []
                for _ in range(rng.randrange(1, 4)):
                    end = start + round(rng.uniform(5, 40), 1)
                    tasks.append(
                        {
                            "kind": rng.choice(["contour", "infill", "support", "travel"]),
                            "start_s": start,
                            "end_s": end,
                        }
                    )
                    start = end
                job["print"] = tasks
            jobs.append(job)
        scen["jobs"] = {"mode": "scripted", "scripted": sorted(jobs, key=lambda j: j["at_s"])}
    if printing:
        scen["print"] = {
            "caps": {k: round(rng.uniform(0.15, 0.7), 2) for k in ("contour", "infill", "support")}
        }
    # A fleet moves at most its diameter per axis in a period (`fleet.scenario.check_fleet`)
    # and sees far enough to stop: most cases keep to that; the rest check the refusal.
    fastest = math.floor(100 * 2 * radius / scen["robots"]["v_max"]) / 100
    if count > 1 and period > fastest and rng.random() < 0.9:
        period = scen["robots"]["period_s"] = max(fastest, 0.1)
    # ... and sees far enough to stop for each other.
    from fleet.scenario import RobotsConfig, sensing_needed  # the rule `check_fleet` applies

    r = scen["robots"]
    group = RobotsConfig(
        count=count, radius=radius, v_max=r["v_max"], a_max=r["a_max"], period_s=r["period_s"]
    )
    needed = sensing_needed(group, group)
    sensing = scen["scenario"]["sensing_radius_m"]
    if count > 1 and sensing < needed and rng.random() < 0.9:
        scen["scenario"]["sensing_radius_m"] = math.ceil(10 * needed) / 10
    note = (
        f"{controller}, {count} robot(s) r={radius} (clearance {clearance}), period {period} s, "
        f"{duration} s, {len(obstacles)} obstacles, {len(zones)} zones, {len(stations)} stations, "
        f"{scen['jobs']['mode']} jobs"
    )
    return Case(f"s{seed}-{index:04d}", floor, scen, controller, note)


# --- the oracle: the map file alone -------------------------------------------------------------


def _poly(entry: Mapping[str, Any], key: str = "polygon") -> Polygon:
    if "rect" in entry:
        return box(*entry["rect"])
    return Polygon(entry[key])


def _axes(v: float | Sequence[float]) -> tuple[float, float]:
    return (float(v), float(v)) if isinstance(v, (int, float)) else (float(v[0]), float(v[1]))


@dataclass
class MapModel:
    """What the map file says, read with tomllib and shapely only."""

    boundary: Polygon
    clearance: float
    default_v_max: tuple[float, float]
    obstacles: list[tuple[str, Polygon]]
    zones: list[tuple[str, BaseGeometry, tuple[float, float]]]
    stations: dict[str, tuple[float, float]]

    @classmethod
    def read(cls, path: Path) -> MapModel:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        fl = data["floor"]
        boundary = _poly(fl, "boundary")
        obstacles = [(o["name"], _poly(o)) for o in data.get("obstacles", [])]
        shapes: dict[str, BaseGeometry] = dict(obstacles)
        raw = {z["name"]: z for z in data.get("zones", [])}

        def full(name: str) -> BaseGeometry:  # a zone's unclipped shape (rings grow from it)
            if name not in shapes:
                z = raw[name]
                shapes[name] = _mitre(full(z["around"]), z["margin"]) if "around" in z else _poly(z)
            return shapes[name]

        zones = [(n, full(n).intersection(boundary), _axes(z["v_max"])) for n, z in raw.items()]
        stations = {
            s["name"]: (float(s["at"][0]), float(s["at"][1])) for s in data.get("stations", [])
        }
        return cls(
            boundary,
            float(fl.get("clearance", 0.0)),
            _axes(fl["default_v_max"]),
            obstacles,
            zones,
            stations,
        )


def confirm_duration(duration: float) -> float:
    """How long the run that confirms a ``job_not_done`` or ``stuck_home`` finding lasts
    (`CONFIRM_FACTOR`)."""
    return max(CONFIRM_FACTOR * duration, duration + CONFIRM_EXTRA_S)


@dataclass(frozen=True)
class Finding:
    kind: str
    robot: str
    t: float
    detail: str
    #: A ``job_not_done`` finding's job when a longer run may still end it (not one that failed
    #: without a reason): `confirm_not_done` judges it again.
    open_job: str = ""

    def __str__(self) -> str:
        who = f" {self.robot}" if self.robot else ""
        return f"{self.kind}{who} at t = {self.t:.2f} s: {self.detail}"


@dataclass
class RunRecord:
    """What a run recorded, in plain data: the oracle's other input."""

    duration: float
    trajectories: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]  # robot -> t, xy, v
    radius: dict[str, float]
    v_max: dict[str, float]
    a_max: dict[str, float]
    return_home: dict[str, bool] = field(default_factory=dict)
    #: (t, event, job, robot, station) as the recorder keeps them.
    events: list[tuple[float, str, str, str, str]] = field(default_factory=list)
    #: (robot, job, kind, start_s, end_s, cap, attempt): caps.csv's rows.
    caps: list[tuple] = field(default_factory=list)


class Oracle:
    """Judges a `RunRecord` against a `MapModel`; `judge` returns the findings."""

    def __init__(self, model: MapModel) -> None:
        self.m = model
        self.walls = model.boundary.exterior
        self.cores = [(n, z.buffer(-LENGTH_TOL, join_style="mitre"), v) for n, z, v in model.zones]
        covered = unary_union([z for _, z, _ in model.zones]) if model.zones else Polygon()
        rest = model.boundary.difference(covered).buffer(-LENGTH_TOL, join_style="mitre")
        self.rest = rest  # where the default limit holds

    def judge(self, run: RunRecord) -> list[Finding]:
        out: list[Finding] = []
        for robot in sorted(run.trajectories):
            out += self.body(robot, run)
            out += self.speeds(robot, run)
        out += self.contacts(run)
        out += self.liveness(run)
        return out

    # (a) the disc in the hall and off the obstacles
    def body(self, robot: str, run: RunRecord) -> list[Finding]:
        t, xy, _ = run.trajectories[robot]
        if len(t) == 0:
            return []
        r = run.radius[robot]
        c = self.m.clearance
        nxt = np.vstack([xy[1:], xy[-1:]])
        segs = shapely.linestrings(np.stack([xy, nxt], axis=1))
        moving = np.any(xy != nxt, axis=1)
        segs = np.where(moving, segs, shapely.points(xy))
        out: list[Finding] = []
        worst: dict[str, tuple[float, int]] = {}
        dist = shapely.distance(segs, self.walls)
        inside = shapely.covers(self.m.boundary, segs)
        dist = np.where(inside, dist, -1.0)
        dists = [("the wall", dist)]
        for name, o in self.m.obstacles:
            d = shapely.distance(segs, o)
            dists.append((f"obstacle {name!r}", d))
        for what, d in dists:
            k = int(np.argmin(d))
            worst[what] = (float(d[k]), k)
        for what, (d, k) in worst.items():
            if d < r - LENGTH_TOL:
                where = "outside the hall" if d < 0 else f"{d:.4f} m from {what}"
                out.append(
                    Finding(
                        "obstacle",
                        robot,
                        float(t[k]),
                        f"the step from ({xy[k, 0]:.3f}, {xy[k, 1]:.3f}) comes {where}, "
                        f"radius {r:g}",
                    )
                )
            elif d < c - LENGTH_TOL:
                out.append(
                    Finding(
                        "clearance",
                        robot,
                        float(t[k]),
                        f"the step from ({xy[k, 0]:.3f}, {xy[k, 1]:.3f}) comes {d:.4f} m from "
                        f"{what}, less than floor.clearance {c:g}",
                    )
                )
        return out

    # (b) zone limits, the robot's own limit, print caps, acceleration
    def speeds(self, robot: str, run: RunRecord) -> list[Finding]:
        t, xy, v = run.trajectories[robot]
        if len(t) < 2:
            return []
        dt = np.diff(t)
        step_v = np.abs(np.diff(xy, axis=0)) / dt[:, None]  # p += dt * v: the same as |v[k]|
        speed = np.maximum(np.abs(v[:-1]), step_v)
        segs = shapely.linestrings(np.stack([xy[:-1], xy[1:]], axis=1))
        still = np.all(xy[:-1] == xy[1:], axis=1)
        segs = np.where(still, shapely.points(xy[:-1]), segs)
        limit = np.full((len(segs), 2), np.inf)
        source = np.full(len(segs), "", dtype=object)
        areas = [(f"zone {n!r}", core, vm) for n, core, vm in self.cores]
        areas.append(("the floor's default_v_max", self.rest, self.m.default_v_max))
        for name, core, vm in areas:
            if core.is_empty:
                continue
            hit = shapely.intersects(segs, core)
            tighter = hit & (min(vm) < limit.min(axis=1))
            source[tighter] = name
            limit[hit] = np.minimum(limit[hit], vm)
        out: list[Finding] = []
        bad = np.flatnonzero(np.any(speed > limit + SPEED_TOL, axis=1))
        if len(bad):
            k = int(bad[np.argmax((speed - limit)[bad].max(axis=1))])
            out.append(
                Finding(
                    "zone_speed",
                    robot,
                    float(t[k]),
                    f"|v| = ({speed[k, 0]:.4f}, {speed[k, 1]:.4f}) m/s over the limit of "
                    f"{source[k]}, ({limit[k, 0]:g}, {limit[k, 1]:g}) m/s, at "
                    f"({xy[k, 0]:.3f}, {xy[k, 1]:.3f}); {len(bad)} step(s)",
                )
            )
        vmax = run.v_max[robot]
        over = np.flatnonzero(np.any(speed > vmax + SPEED_TOL, axis=1))
        if len(over):
            k = int(over[0])
            out.append(
                Finding(
                    "robot_speed",
                    robot,
                    float(t[k]),
                    f"|v| = ({speed[k, 0]:.4f}, {speed[k, 1]:.4f}) m/s over its v_max {vmax:g}; "
                    f"{len(over)} step(s)",
                )
            )
        acc = np.abs(np.diff(v, axis=0)) / dt[:, None]
        amax = run.a_max[robot]
        over = np.flatnonzero(np.any(acc > amax + 1e-6, axis=1))
        if len(over):
            k = int(over[0])
            out.append(
                Finding(
                    "accel",
                    robot,
                    float(t[k]),
                    f"|dv/dt| = ({acc[k, 0]:.4f}, {acc[k, 1]:.4f}) over its a_max {amax:g}; "
                    f"{len(over)} step(s)",
                )
            )
        for rob, job, kind, s0, s1, cap, *_ in run.caps:
            if rob != robot:
                continue
            eps = 1e-9 * max(1.0, s1)
            sel = np.flatnonzero((t[:-1] < s1 - eps) & (t[1:] > s0 + eps))
            hit = sel[np.any(speed[sel] > cap + SPEED_TOL, axis=1)]
            if len(hit):
                k = int(hit[0])
                out.append(
                    Finding(
                        "print_speed",
                        robot,
                        float(t[k]),
                        f"|v| = ({speed[k, 0]:.4f}, {speed[k, 1]:.4f}) m/s over the {kind} cap "
                        f"{cap:g} of job {job} ({s0:.2f}..{s1:.2f} s); {len(hit)} step(s)",
                    )
                )
        return out

    # (c) robots apart, at common samples and between them
    def contacts(self, run: RunRecord) -> list[Finding]:
        names = sorted(r for r in run.trajectories if len(run.trajectories[r][0]))
        if len(names) < 2:
            return []
        times = np.unique(np.concatenate([run.trajectories[r][0] for r in names]))
        pos = {}
        for r in names:
            t, xy, _ = run.trajectories[r]
            # Before its first sample or after its last a robot stands where it was.
            pos[r] = np.column_stack([np.interp(times, t, xy[:, 0]), np.interp(times, t, xy[:, 1])])
        out = []
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                need = run.radius[a] + run.radius[b] - LENGTH_TOL
                d0 = pos[a] - pos[b]
                g = np.diff(d0, axis=0)
                g2 = np.sum(g * g, axis=1)
                with np.errstate(invalid="ignore", divide="ignore"):
                    s = np.where(g2 > 0, -np.sum(d0[:-1] * g, axis=1) / g2, 0.0)
                s = np.clip(s, 0.0, 1.0)
                closest = np.hypot(*(d0[:-1] + s[:, None] * g).T)
                closest = np.append(closest, np.hypot(*d0[-1]))
                bad = closest < need
                # One finding per contact episode (consecutive steps in contact).
                starts = np.flatnonzero(bad & ~np.r_[False, bad[:-1]])
                for k in starts:
                    end = k
                    while end + 1 < len(bad) and bad[end + 1]:
                        end += 1
                    j = k + int(np.argmin(closest[k : end + 1]))
                    out.append(
                        Finding(
                            "contact",
                            a,
                            float(times[j]),
                            f"{a} and {b} {closest[j]:.3f} m apart (radii {run.radius[a]:g} + "
                            f"{run.radius[b]:g}) near ({pos[a][j, 0]:.2f}, {pos[a][j, 1]:.2f}), "
                            f"{times[end] - times[k]:.2f} s in contact",
                        )
                    )
        return out

    # (d), (e), (f): liveness from the events
    def liveness(self, run: RunRecord) -> list[Finding]:
        end = run.duration
        holder: dict[str, str | None] = {}  # job -> robot holding it now
        released: dict[str, float] = {}
        done: dict[str, str] = {}  # job -> "delivered" / "failed: reason"
        arrived: set[str] = set()
        open_since: dict[str, float] = {}  # job -> unassigned since
        waiting: list[tuple[str, float, float]] = []  # (job, from, to) unassigned intervals
        busy: dict[str, list[tuple[float, float]]] = defaultdict(list)  # robot -> job intervals
        held_from: dict[tuple[str, str], float] = {}
        # In the order recorded (a job released and assigned at one instant may carry times a
        # rounding error apart, so sorting by time could put the assignment first).
        for t, ev, job, robot, station in run.events:
            if ev == "released":
                released[job] = t
                open_since[job] = t
            elif ev == "assigned":
                if job in open_since:
                    waiting.append((job, open_since.pop(job), t))
                holder[job] = robot
                held_from[(job, robot)] = t
            elif ev in ("delivered", "handed_back", "reoffered", "failed"):
                who = holder.get(job)
                if who is not None and (job, who) in held_from:
                    busy[who].append((held_from.pop((job, who)), t))
                holder[job] = None
                arrived.discard(job)
                if ev == "delivered":
                    done[job] = "delivered"
                    open_since.pop(job, None)
                elif ev == "failed":
                    done[job] = f"failed: {station}" if station else "failed without a reason"
                    open_since.pop(job, None)
                elif job not in done:
                    open_since[job] = t
            elif ev == "arrived":
                arrived.add(job)
        for (_job, who), t0 in held_from.items():
            busy[who].append((t0, end))
        for job, t0 in open_since.items():
            waiting.append((job, t0, end))

        out: list[Finding] = []
        long_run = end >= LIVENESS_MIN_S
        # (f) every job ends delivered or failed with a reason
        for job, t0 in sorted(released.items(), key=lambda kv: kv[1]):
            state = done.get(job)
            if state == "failed without a reason":
                out.append(Finding("job_not_done", "", end, f"job {job} failed without a reason"))
            elif state is None and long_run and t0 <= end - DONE_GRACE_S:
                who = holder.get(job)
                how = f"held by {who}" if who else "unassigned"
                out.append(
                    Finding(
                        "job_not_done",
                        who or "",
                        end,
                        f"job {job} released at {t0:.1f} s is neither delivered nor failed at "
                        f"the end ({how})",
                        open_job=job,
                    )
                )
        # (e) no job waits beside an idle robot
        robots = sorted(run.trajectories)
        for job, a, b in waiting:
            if b - a < WAIT_S:
                continue
            for robot in robots:
                free = _gaps(sorted(busy[robot]), a, b)
                longest = max((y - x for x, y in free), default=0.0)
                if longest >= WAIT_S:
                    x, y = max(free, key=lambda g: g[1] - g[0])
                    out.append(
                        Finding(
                            "job_waiting",
                            robot,
                            x,
                            f"job {job} unassigned from {a:.1f} to {b:.1f} s while {robot} was "
                            f"idle from {x:.1f} to {y:.1f} s",
                        )
                    )
                    break
        # (d) no robot stuck for good
        if long_run:
            # Idle robots of one group trade home spots (fleet.engine.homes): an idle robot's
            # home is the start spot nearest to where it ended.
            starts = _start_spots(run.trajectories)
            for robot in robots:
                t, xy, _ = run.trajectories[robot]
                if len(t) == 0 or t[-1] < end - 1.0:
                    continue
                win = t >= t[-1] - STUCK_S
                spread = float(np.max(np.hypot(*(xy[win] - xy[win][0]).T)))
                jobs = [j for j, who in holder.items() if who == robot]
                if spread >= STUCK_RADIUS_M and (
                    jobs or spread >= WANDER_M or not run.return_home.get(robot)
                ):
                    continue
                goal = next((j for j in jobs if j not in arrived), None)
                if goal is not None:
                    since = min(held_from.get((j, robot), end) for j in jobs)
                    if since <= t[-1] - STUCK_S:
                        out.append(
                            Finding(
                                "stuck",
                                robot,
                                float(t[-1] - STUCK_S),
                                f"has job {goal} (since {since:.1f} s) and stayed within "
                                f"{spread:.2f} m of ({xy[-1, 0]:.2f}, {xy[-1, 1]:.2f}) for the "
                                f"last {STUCK_S:g} s",
                            )
                        )
                elif not jobs and run.return_home.get(robot):
                    home = starts[int(np.argmin(np.hypot(*(starts - xy[-1]).T)))]
                    away = float(math.dist(home, xy[-1]))
                    gap = np.hypot(*(xy[win] - home).T)
                    # Still, or wandering round a spot away from home all along, and no nearer
                    # it than at first (not one sent off home, aside, within the window).
                    nearer = spread >= STUCK_RADIUS_M and (
                        gap.min() < max(gap[0] - STUCK_RADIUS_M, STUCK_RADIUS_M)
                    )
                    idle_since = max((y for _, y in busy[robot]), default=0.0)
                    if away > 0.5 and not nearer and idle_since <= t[-1] - STUCK_S:
                        out.append(
                            Finding(
                                "stuck_home",
                                robot,
                                float(t[-1] - STUCK_S),
                                f"idle since {idle_since:.1f} s, {away:.2f} m from home "
                                f"({home[0]:.2f}, {home[1]:.2f}), stayed within {spread:.2f} m "
                                f"and no nearer home for the last {STUCK_S:g} s",
                            )
                        )
        return out


def _gaps(busy: list[tuple[float, float]], a: float, b: float) -> list[tuple[float, float]]:
    """The parts of [a, b] outside the `busy` intervals (sorted by start)."""
    out, cur = [], a
    for x, y in busy:
        if y <= cur or x >= b:
            continue
        if x > cur:
            out.append((cur, min(x, b)))
        cur = max(cur, y)
    if cur < b:
        out.append((cur, b))
    return out


# --- running a case ----------------------------------------------------------------------------


@dataclass
class Outcome:
    """What running and judging one case gave."""

    name: str
    controller: str
    status: str  # "ok", "refused" or "failed" (findings not in INFO_KINDS, a run error, a crash)
    findings: list[Finding] = field(default_factory=list)
    engine: dict[str, int] = field(default_factory=dict)
    refusal: str = ""
    traceback: str = ""
    wall_s: float = 0.0
    note: str = ""

    @property
    def engine_flagged(self) -> bool:
        """Whether the engine's own checker counted a safety violation (saved even when the
        oracle finds nothing: the two disagree)."""
        return any(self.engine.get(k, 0) for k in SAFETY_KEYS)


def engine_counts(summary: Mapping[str, Any]) -> dict[str, int]:
    """The engine's own counts, to print beside the oracle's."""
    v = summary.get("violations", {})
    return {
        "collision": int(v.get("collision", 0)),
        "obstacle": int(v.get("obstacle", 0)),
        "speed_zone": int(v.get("speed_zone", 0)),
        "print_speed": int(v.get("print_speed", 0)),
        "deadlocks": int(summary.get("engine", {}).get("deadlocks", 0)),
        "fallbacks": int(summary.get("solver", {}).get("fallbacks", 0)),
        "stuck_robots": len(summary.get("stuck_robots", [])),
    }


def controller_errors(summary: Mapping[str, Any]) -> list[Finding]:
    """A finding per robot whose controller raised while it had somewhere to go (its agent
    braked it instead: the run goes on, but the controller has a bug)."""
    return [
        Finding(
            "controller_error",
            r["id"],
            0.0,
            f"{r['goal_errors']} of its {r['goal_commands']} commands with somewhere to go were "
            "errors (the controller raised; the agent's log has the first traceback)",
        )
        for r in summary.get("per_robot", [])
        if r.get("goal_errors", 0) > 0
    ]


def record_of(world: Any) -> RunRecord:
    """The oracle's input from a finished `World` (the recorder's samples at full precision)."""
    sc = world.scenario
    trajectories = {r: tr.arrays() for r, tr in world.recorder.trajectories.items()}
    robots = world.robots
    return RunRecord(
        duration=float(world.env.now),
        trajectories=trajectories,
        radius={r: s.spec.radius for r, s in robots.items()},
        v_max={r: s.spec.v_max for r, s in robots.items()},
        a_max={r: s.spec.a_max for r, s in robots.items()},
        return_home={r: bool(s.return_home) for r, s in robots.items()},
        events=[(e.t, e.event, e.job, e.robot, e.station) for e in world.recorder.events],
        caps=[tuple(row) for row in world.cap_rows()] if sc.print_caps else [],
    )


def job_ends(
    events: Iterable[tuple[float, str, str, str, str]],
) -> dict[str, tuple[str, float, str]]:
    """Job -> (how it ended, when, who holds it at the end), from (t, event, job, robot,
    station) events as the recorder keeps them: "delivered", "failed: <reason>" or "failed
    without a reason" at the time of that event, or "" (not ended) with the time of its last
    event. The same reading as `Oracle.liveness`'s."""
    out: dict[str, tuple[str, float, str]] = {}
    for t, ev, job, robot, station in events:
        state, _, who = out.get(job, ("", t, ""))
        if ev == "assigned":
            who = robot
        elif ev in ("delivered", "handed_back", "reoffered", "failed"):
            who = ""
            if ev == "delivered":
                state = "delivered"
            elif ev == "failed":
                state = f"failed: {station}" if station else "failed without a reason"
            elif state:
                continue  # handed back after it ended: it stays ended, when it was
        elif ev != "released":
            continue
        out[job] = (state, t, who)
    return out


def confirm_not_done(
    findings: list[Finding], end: float, long_s: float, long_events: Iterable[tuple]
) -> list[Finding]:
    """`findings` with each open ``job_not_done`` (a job not ended at `end`, the first run's
    end) judged by the run of `long_s` seconds whose events are `long_events`: a job ended there
    (delivered, or failed with a reason) becomes ``job_late``; one not ended, or failed without
    a reason, stays ``job_not_done``, saying the longer run confirmed it. Only these jobs are
    judged: jobs released after `end` do not matter."""
    ends = job_ends(long_events)
    out = []
    for f in findings:
        if f.kind != "job_not_done" or not f.open_job:
            out.append(f)
            continue
        job = f.open_job
        state, t, who = ends.get(job, ("", end, ""))
        first = f.detail.split(" is neither", 1)[0]  # "job j released at T s"
        held = f"held by {f.robot}" if f.robot else "unassigned"
        if state and state != "failed without a reason":
            how = "delivered" if state == "delivered" else state.replace(": ", " (") + ")"
            out.append(
                Finding(
                    "job_late",
                    f.robot,
                    t,
                    f"{first} was not done at the end ({end:g} s, {held}); {how} at {t:.1f} s "
                    f"in a {long_s:g}-s run of the same case",
                )
            )
            continue
        now = "failed without a reason" if state else (f"held by {who}" if who else "unassigned")
        out.append(
            Finding(
                "job_not_done",
                f.robot,
                f.t,
                f"{f.detail}; confirmed by a {long_s:g}-s run of the same case ({now} at its end)",
            )
        )
    return out


def confirm_home(
    findings: list[Finding],
    end: float,
    long_s: float,
    long_trajectories: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
) -> list[Finding]:
    """`findings` with each ``stuck_home`` (an idle robot held away from home up to `end`, the
    first run's end) judged by the run of `long_s` seconds whose trajectories (robot -> t, xy,
    v) are `long_trajectories`: a robot within `STUCK_RADIUS_M` of a home (where a robot
    started: idle robots of one group trade them) at some time after `end` becomes
    ``home_late``; the others stay, saying the longer run confirmed them."""
    out = []
    starts = _start_spots(long_trajectories)
    for f in findings:
        if f.kind != "stuck_home":
            out.append(f)
            continue
        t, xy, _ = long_trajectories[f.robot]
        after = t > end
        gap = np.min(np.hypot(*(xy[after][:, None, :] - starts[None]).transpose(2, 0, 1)), axis=1)
        home = t[after][gap <= STUCK_RADIUS_M]
        if len(home):
            how = f"home at {home[0]:.1f} s in a {long_s:g}-s run of the same case"
            out.append(Finding("home_late", f.robot, float(home[0]), f"{f.detail}; {how}"))
        else:
            why = f"confirmed by a {long_s:g}-s run of the same case (not home at its end)"
            out.append(replace(f, detail=f"{f.detail}; {why}"))
    return out


def _start_spots(
    trajectories: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
) -> np.ndarray:
    """``(n, 2)``: where each robot of a run started (every robot's home at first)."""
    return np.array([xy[0] for _, xy, _ in trajectories.values() if len(xy)])


def _to_confirm(f: Finding) -> bool:
    """Whether a longer run of the case may still turn `f` into an informational finding."""
    return bool(f.open_job) or f.kind == "stuck_home"


def run_folder(
    folder: Path, name: str = "", controller: str = "", note: str = "", confirm: bool = True
) -> Outcome:
    """Load, run and judge the case in `folder` (floor.toml + scen.toml). With `confirm`, a
    ``job_not_done`` or ``stuck_home`` finding is judged again by a longer run
    (`confirm_not_done`, `confirm_home`; run only when there is one); the longer run is
    written to `folder`/run-long when it confirms one."""
    from fleet.engine import World
    from fleet.errors import FleetError
    from fleet.scenario import load_scenario

    out = Outcome(name or folder.name, controller, "ok", note=note)
    start = time.perf_counter()
    try:
        try:
            scenario = load_scenario(folder / "scen.toml")
            out.controller = out.controller or scenario.controller.name
            world = World(scenario)
        except FleetError as exc:
            out.status, out.refusal = "refused", str(exc).splitlines()[0]
            return out
        try:
            result = world.run()
        except FleetError as exc:
            out.status = "failed"
            out.findings.append(Finding("run_error", "", 0.0, str(exc).splitlines()[0]))
            out.traceback = traceback.format_exc()
            return out
        out.engine = engine_counts(result.summary)
        model = MapModel.read(folder / "floor.toml")
        out.findings = Oracle(model).judge(record_of(world)) + controller_errors(result.summary)
        long_world = None
        if confirm and any(_to_confirm(f) for f in out.findings):
            long_s = confirm_duration(scenario.duration_s)
            try:
                long_world = World(scenario.override(duration=long_s))
                long_world.run()
            except FleetError as exc:  # the first run's findings stand, unconfirmed
                why = str(exc).splitlines()[0]
                out.findings = [
                    replace(
                        f, detail=f"{f.detail}; not confirmed: the {long_s:g}-s run raised {why}"
                    )
                    if _to_confirm(f)
                    else f
                    for f in out.findings
                ]
                long_world = None
            else:
                events = [
                    (e.t, e.event, e.job, e.robot, e.station) for e in long_world.recorder.events
                ]
                end = float(world.env.now)
                out.findings = confirm_not_done(out.findings, end, long_s, events)
                out.findings = confirm_home(
                    out.findings, end, long_s, record_of(long_world).trajectories
                )
        if any(f.kind not in INFO_KINDS for f in out.findings):
            out.status = "failed"
        if out.status == "failed" or out.engine_flagged:
            world.write(folder / "run")
            if long_world is not None and (_has(out, "job_not_done") or _has(out, "stuck_home")):
                long_world.write(folder / "run-long")
    except Exception as exc:  # noqa: BLE001 - every other exception is a finding
        out.status = "failed"
        out.findings.append(Finding("crash", "", 0.0, f"{type(exc).__name__}: {exc}"))
        out.traceback = traceback.format_exc()
    finally:
        out.wall_s = time.perf_counter() - start
    return out


def run_case(args: tuple) -> Outcome:
    """Generate case (seed, index) into a scratch folder, run and judge it; on findings copy
    the folder to `out`. A module-level function, so worker processes can take it. `args`:
    (seed, index, controller, out, quick[, mpc_options[, fleet]]), as `generate_case`'s."""
    seed, index, controller, out_dir, quick = args[:5]
    mpc_options: dict[str, Any] = args[5] if len(args) > 5 else {}
    fleet: tuple[int, int] | None = args[6] if len(args) > 6 else None
    case = generate_case(seed, index, controller, quick, mpc_options, fleet)
    with tempfile.TemporaryDirectory(prefix="fuzz-floors-") as tmp:
        folder = case.write(Path(tmp) / case.name)
        outcome = run_folder(folder, case.name, case.controller, case.note)
        if outcome.status == "failed" or outcome.engine_flagged:
            dest = Path(out_dir) / case.name
            if dest.exists():
                shutil.rmtree(dest)
            shutil.copytree(folder, dest)
            flags = f"--controller {controller} " + ("--quick " if quick else "")
            flags += "".join(f"--mpc-option {k}={v!r} " for k, v in mpc_options.items())
            flags += f"--fleet {fleet[0]}-{fleet[1]} " if fleet else ""
            write_findings(dest, outcome, f"{flags}--seed {seed} --only {index}")
    return outcome


def write_findings(folder: Path, outcome: Outcome, generated_by: str = "") -> None:
    """findings.txt: what failed, the engine's counts, and the commands that rerun the case
    (`generated_by`: the script's options that generate it again)."""
    lines = [f"case {outcome.name}: {outcome.note}", "", "findings:"]
    lines += [f"  {f}" for f in outcome.findings]
    lines += [
        "",
        "engine's own counts: " + ", ".join(f"{k} {v}" for k, v in outcome.engine.items()),
    ]
    if outcome.engine_flagged and not outcome.findings:
        lines += ["(the engine counted safety violations the oracle did not find)"]
    lines += [
        "",
        "rerun and judge this folder:",
        f"  python scripts/fuzz_floors.py --case {folder}",
    ]
    if generated_by:
        lines += [f"  (generated by: python scripts/fuzz_floors.py {generated_by})"]
    lines += [f"  or: cd {folder} && fleet run scen.toml --out runs/case --no-figures"]
    if (folder / "run").exists():
        lines += ["the engine's run directory is in run/ (trajectories.csv, events.csv ...)"]
    if (folder / "run-long").exists():
        lines += ["the longer run that confirmed job_not_done or stuck_home is in run-long/"]
    if outcome.traceback:
        lines += ["", outcome.traceback]
    (folder / "findings.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")


# --- the harness -------------------------------------------------------------------------------


@dataclass
class Tally:
    outcomes: list[Outcome] = field(default_factory=list)

    def add(self, o: Outcome) -> None:
        self.outcomes.append(o)

    def kinds(self) -> dict[str, tuple[int, int]]:
        """Finding kind -> (findings, runs with it)."""
        n: Counter[str] = Counter()
        runs: Counter[str] = Counter()
        for o in self.outcomes:
            here = Counter(f.kind for f in o.findings)
            n.update(here)
            runs.update(here.keys())
        return {k: (n[k], runs[k]) for k in KINDS}


def report(tally: Tally, out_dir: Path, elapsed: float) -> str:
    outs = tally.outcomes
    ran = [o for o in outs if o.status != "refused"]
    failed = [o for o in outs if o.status == "failed"]
    refused = [o for o in outs if o.status == "refused"]
    lines = [
        f"floors: {len(outs)} ({len(ran)} run, {len(refused)} refused), "
        f"{len(failed)} with findings; {elapsed:.0f} s wall",
    ]
    for kind, what in (
        ("job_late", "late jobs (not done at the end, done in a longer run of the case"),
        ("home_late", "robots home late (held away from home at the end, home in a longer run"),
    ):
        runs = [o for o in outs if _has(o, kind)]
        if runs:
            lines.append(
                f"{what}; informational): {tally.kinds()[kind][0]} in {len(runs)} runs, "
                f"{sum(1 for o in runs if o.status != 'failed')} of them without other findings"
            )
    by_ctl = Counter(o.controller for o in ran)
    walls = [o.wall_s for o in ran]
    if walls:
        lines.append(
            f"wall time per floor: median {statistics.median(walls):.2f} s, max {max(walls):.1f} s"
            + "".join(
                f"; {c} median "
                f"{statistics.median([o.wall_s for o in ran if o.controller == c]):.2f} s"
                f" ({n} runs)"
                for c, n in sorted(by_ctl.items())
            )
        )
    lines += ["", f"{'finding':<14} {'count':>6} {'runs':>6}   follower  mpc"]
    for kind, (n, runs) in tally.kinds().items():
        per = Counter(o.controller for o in outs if _has(o, kind))
        lines.append(
            f"{kind:<14} {n:>6} {runs:>6}   {per.get('follower', 0):>8} {per.get('mpc', 0):>4}"
        )
    keys = (
        "collision",
        "obstacle",
        "speed_zone",
        "print_speed",
        "deadlocks",
        "fallbacks",
        "stuck_robots",
    )
    total = {k: sum(o.engine.get(k, 0) for o in ran) for k in keys}
    nonzero = {k: sum(1 for o in ran if o.engine.get(k, 0)) for k in keys}
    lines += ["", "engine's own counts (total / runs):"]
    lines += ["  " + ", ".join(f"{k} {total[k]}/{nonzero[k]}" for k in keys)]
    # Where the oracle and the engine's checker disagree on contact and obstacles.
    both = sum(1 for o in ran if o.engine.get("collision") and _has(o, "contact"))
    oracle_only = [o.name for o in ran if _has(o, "contact") and not o.engine.get("collision")]
    engine_only = [o.name for o in ran if o.engine.get("collision") and not _has(o, "contact")]
    lines.append(
        f"  contact: both {both}, oracle only {len(oracle_only)} {oracle_only[:8]}, "
        f"engine only {len(engine_only)} {engine_only[:8]}"
    )
    # The engine judges against the map's free space (clearance, mitred corners): compare it
    # with the oracle's obstacle and clearance findings together.
    near = [o for o in ran if _has(o, "obstacle") or _has(o, "clearance")]
    oracle_only = [o.name for o in near if not o.engine.get("obstacle")]
    engine_only = [o.name for o in ran if o.engine.get("obstacle") and o not in near]
    lines.append(
        f"  obstacle/clearance: both {len(near) - len(oracle_only)}, oracle only "
        f"{len(oracle_only)} {oracle_only[:8]}, engine only {len(engine_only)} {engine_only[:8]}"
    )
    if refused:
        lines += ["", "refused (first line of the loader's message, by kind):"]
        why = Counter(_refusal_kind(o.refusal) for o in refused)
        for k, n in why.most_common():
            example = next(o for o in refused if _refusal_kind(o.refusal) == k)
            lines.append(f"  {n:>4}  {k}   e.g. {example.name}: {example.refusal[:160]}")
    if failed:
        lines += ["", f"failing cases (saved under {out_dir}):"]
        for o in failed:
            kinds = Counter(f.kind for f in o.findings)
            first = o.findings[0]
            lines.append(f"  {o.name} [{o.controller}] {dict(kinds)}: {str(first)[:200]}")
    return "\n".join(lines)


def _has(o: Outcome, kind: str) -> bool:
    return any(f.kind == kind for f in o.findings)


def _refusal_kind(message: str) -> str:
    """A refusal's field without its file, value and entry names, to group refusals."""
    rest = message.split(": ", 1)[-1]  # "<file>: <field> = <value>: <rule>"
    field_ = rest.split(" = ", 1)[0] if " = " in rest else rest[:60]
    return re.sub(r"\[\d+\] \([^)]*\)", "[i]", field_)


def _progress(total: int) -> Iterator[None]:
    """Called once per finished floor: a line redrawn on a terminal, a plain line every tenth
    (and at the end) otherwise."""
    start = time.perf_counter()
    tty = sys.stdout.isatty()
    step = max(1, total // 10)
    done = 0
    while True:
        stats = yield
        done += 1
        elapsed = time.perf_counter() - start
        eta = elapsed / done * (total - done)
        failed, refused = stats
        line = (
            f"{done:>5} / {total} floors  {failed} failing  {refused} refused  "
            f"{elapsed:6.0f} s elapsed, ~{eta:.0f} s left"
        )
        width = 30
        bar = "#" * int(width * done / total)
        if tty:
            print(f"\r[{bar:<{width}}] {line}", end="", flush=True)
            if done == total:
                print()
        elif done % step == 0 or done == total:
            print(line, flush=True)


def fuzz(
    floors: int,
    seed: int,
    controller: str,
    out_dir: Path,
    workers: int = 1,
    first: int = 0,
    show: bool = True,
    quick: bool = False,
    mpc_options: dict[str, Any] | None = None,
    fleet: tuple[int, int] | None = None,
) -> Tally:
    """Generate, run and judge `floors` cases (indices first .. first + floors - 1), MPC cases
    with `mpc_options` as controller options, `fleet` robots if given (`generate_case`)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    tally = Tally()
    opts = dict(mpc_options or {})
    tasks = [
        (seed, i, controller, str(out_dir), quick, opts, fleet)
        for i in range(first, first + floors)
    ]
    progress = _progress(floors) if show else None
    if progress is not None:
        next(progress)

    log = (out_dir / RESULTS).open("a", encoding="utf-8")

    def take(o: Outcome) -> None:
        tally.add(o)
        # One line per case as it finishes, so a run stopped half-way can still be counted.
        row = {
            "case": o.name,
            "controller": o.controller,
            "status": o.status,
            "findings": dict(Counter(f.kind for f in o.findings)),
            "engine": o.engine,
            "wall_s": round(o.wall_s, 3),
            "refusal": o.refusal,
        }
        log.write(json.dumps(row) + "\n")
        log.flush()
        if progress is not None:
            failed = sum(1 for x in tally.outcomes if x.status == "failed")
            refused = sum(1 for x in tally.outcomes if x.status == "refused")
            progress.send((failed, refused))

    with log:
        if workers <= 1:
            for task in tasks:
                take(run_case(task))
        else:
            with multiprocessing.get_context("spawn").Pool(workers, maxtasksperchild=20) as pool:
                for o in pool.imap_unordered(run_case, tasks):
                    take(o)
                # Let the workers exit on their own: the block's exit terminates them, which
                # leaks their semaphores (a resource_tracker warning at shutdown).
                pool.close()
                pool.join()
    tally.outcomes.sort(key=lambda o: o.name)
    return tally


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--floors", type=int, default=1000, help="cases to generate and run")
    ap.add_argument("--seed", type=int, default=1, help="master seed")
    ap.add_argument("--first", type=int, default=0, help="index of the first case")
    ap.add_argument("--only", type=int, help="run only case INDEX of --seed")
    ap.add_argument(
        "--workers", "--jobs", type=int, default=1, help="parallel processes (default 1)"
    )
    ap.add_argument("--controller", choices=["follower", "mpc", "both"], default="both")
    ap.add_argument("--out", type=Path, default=Path("fuzz-floors-out"), help="failing cases")
    ap.add_argument("--case", type=Path, help="rerun and judge one case folder instead")
    ap.add_argument("--write", type=Path, help="with --only: write the case folder here, not run")
    ap.add_argument("--quick", action="store_true", help="small fleets, short runs (the tests')")
    ap.add_argument(
        "--mpc-option",
        action="append",
        default=[],
        type=_mpc_option,
        metavar="KEY=VALUE",
        help="an MPC controller option for the MPC cases (a TOML value: reuse_ticks=4); repeat",
    )
    ap.add_argument(
        "--fleet",
        type=_fleet_range,
        metavar="MIN-MAX",
        help="robots per case, drawn from MIN..MAX for either controller (default: 1-8, "
        "weighted to small fleets for followers, uniform for the MPC); the floors stay the same",
    )
    return ap


def _fleet_range(text: str) -> tuple[int, int]:
    lo, sep, hi = text.partition("-")
    try:
        pair = (int(lo), int(hi if sep else lo))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--fleet {text!r}: expected MIN-MAX, e.g. 4-12") from None
    if not 1 <= pair[0] <= pair[1]:
        raise argparse.ArgumentTypeError(f"--fleet {text!r}: need 1 <= MIN <= MAX")
    return pair


def _mpc_option(text: str) -> tuple[str, Any]:
    """``key=value`` with a TOML value (``reuse_ticks=4``, ``cost="quadratic"``)."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"--mpc-option {text!r}: expected KEY=VALUE")
    try:
        parsed = tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value.strip()  # a bare word: a string
    return key.strip(), parsed


def main(argv: Iterable[str] | None = None) -> int:
    args = parser().parse_args(None if argv is None else list(argv))
    if args.case is not None:
        o = run_folder(args.case)
        print(f"{o.name} [{o.controller}]: {o.status} in {o.wall_s:.1f} s {o.refusal}")
        for f in o.findings:
            print(f"  {f}")
        print("  engine: " + ", ".join(f"{k} {v}" for k, v in o.engine.items()))
        if o.traceback:
            print(o.traceback)
        return 1 if o.status == "failed" else 0
    if args.only is not None:
        if args.write is not None:
            case = generate_case(
                args.seed, args.only, args.controller, args.quick, dict(args.mpc_option), args.fleet
            )
            print(case.write(args.write / case.name), case.note)
            return 0
        args.first, args.floors = args.only, 1
    # Rows of an earlier run stay in the file: say so, lest they be counted as this run's.
    log = args.out / RESULTS
    earlier = len(log.read_text(encoding="utf-8").splitlines()) if log.is_file() else 0
    print(
        f"fuzz floors: {args.floors} floors from index {args.first}, seed {args.seed}, "
        f"controller {args.controller}, {args.workers} worker(s); failing cases to {args.out}"
        + (f"; MPC options {dict(args.mpc_option)}" if args.mpc_option else "")
        + (f"; {args.fleet[0]}-{args.fleet[1]} robots a case" if args.fleet else "")
        + (f"; appending to {log} ({earlier} earlier row{'s' * (earlier != 1)})" if earlier else "")
    )
    start = time.perf_counter()
    tally = fuzz(
        args.floors,
        args.seed,
        args.controller,
        args.out,
        args.workers,
        args.first,
        quick=args.quick,
        mpc_options=dict(args.mpc_option),
        fleet=args.fleet,
    )
    print(report(tally, args.out, time.perf_counter() - start))
    return 1 if any(o.status == "failed" for o in tally.outcomes) else 0


if __name__ == "__main__":
    sys.exit(main())
