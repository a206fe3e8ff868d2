"""The HTML replay of a finished run: one self-contained file that animates the fleet.

The page is a template, a style sheet and a script shipped beside this module
(``replay_page/replay.html``, ``replay.css``, ``replay.js``). `write_replay` reads a run
directory (never re-running anything) and writes one HTML file with that CSS and JavaScript
inlined and the run's data embedded as JSON (``<script type="application/json"
id="replay-data">``). It needs no server and fetches nothing: no URL appears in the page, so it
works offline and from ``file://``.

The page fills its window: the floor canvas takes the space left of the side panel and above
the controls, at the largest scale that shows the whole floor. It draws speed zones in the
colours of `fleet.view.figures.zone_colours`, obstacles, the clearance band, rough floor,
labelled stations and a scale bar; each robot as a filled circle of its radius in its own
colour with a velocity tick, its planned horizon (``plans.csv``) as a thin dashed line, and its
job state (idle, to station, printing, arrived and waiting for the print) as a ring and a label;
a print that its robot will hand back (scrapped, ``attempts.csv``) has a dashed ring, and a red
cross marks where a robot handed a job back, for `HANDBACK_MARK_S` simulated seconds after;
with ``[battery]`` the side panel also shows each robot's charge and whether it is charging.
Labels never overlap: each is tried at several places around its robot, robots close together
share one label, and a label with no free place is shortened, then left out. The side panel
holds the robots and the jobs with their state at the current time, and the legend. Controls:
play/pause, a speed select, a time slider and the current time.

The page is scriptable, for tests and for people: it reads ``#t=SECONDS`` from its URL at load
and on every hash change, and exposes ``window.replaySeek(t)``, ``replayTime()``,
``replayView()`` (the world-to-pixel map in use: `View`'s fields plus the canvas's ``left`` and
``top`` in the page and the ``area`` it was fitted into), ``replayLabels()`` (the label
rectangles drawn, in canvas pixels), ``replayScaleBar()``, ``replayStates()`` (each robot's
state ``{key, text}`` and each shown job's state text, as the side panel shows them) and
``replayHandbacks()`` (the hand-back crosses drawn: robot, job, attempt, t and canvas x, y).
The map is `view_transform`
mirrored in the script, so a test can recompute it from the area the page reports. Positions
between two embedded samples are interpolated linearly; samples are thinned by `simplify` so
that this interpolation stays within a tolerance (1 cm by default) of every recorded sample.
"""

from __future__ import annotations

import html
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from fleet.floor import Floor
from fleet.view.figures import (
    KIND_COLOURS,
    RunData,
    csv_number,
    load_run,
    read_csv_rows,
    zone_colours,
    zone_label,
)

__all__ = [
    "REPLAY_HTML",
    "ROBOT_COLOURS",
    "DEFAULT_RADIUS_M",
    "HANDBACK_MARK_S",
    "VIEW_MARGIN_PX",
    "View",
    "Plan",
    "view_transform",
    "robot_colour",
    "simplify",
    "load_plans",
    "replay_data",
    "replay_html",
    "page_part",
    "write_replay",
]

#: File name `write_replay` writes into the run directory by default.
REPLAY_HTML = "replay.html"
#: Robot colours, in robot id order (cycled with darker shades beyond). Chosen apart from the
#: zone scale (white to orange), the obstacle red, the clearance grey, the station navy and the
#: print-kind colours of the job-state rings.
ROBOT_COLOURS: tuple[str, ...] = (
    "#1f77b4",
    "#e377c2",
    "#17becf",
    "#8c564b",
    "#6a3d9a",
    "#008080",
    "#bcbd22",
    "#ff00ff",
)
#: Robot radius (m) drawn when neither the summary nor the map gives one.
DEFAULT_RADIUS_M = 0.4
#: How long (simulated s) the page marks the spot where a robot handed a job back.
HANDBACK_MARK_S = 10.0
#: Pixels the page keeps free around the floor (`view_transform`'s default, sent to the page).
VIEW_MARGIN_PX = 20

_PLAN_COLUMNS = ("t_sent", "robot", "k", "t", "x", "y")
_OBSTACLE_COLOUR = "#6b0f0f"
_CLEARANCE_COLOUR = "#cfcfcf"
_STATION_COLOUR = "#1f3b73"
#: The page's parts, package data beside this module; the template names the others.
_PAGE_DIR = "replay_page"
_SLOTS = re.compile(r"@(TITLE|CSS|SCRIPT|DATA)@")


@dataclass(frozen=True)
class View:
    """The page's world-to-canvas map: pixel ``(x0 + scale * x, y0 - scale * y)``.

    Canvas pixel ``(col, row)`` covers ``[col, col + 1) x [row, row + 1)`` of that map; the
    canvas is `width` x `height` CSS pixels (the page reports where it sits, `replayView`).
    """

    scale: float
    x0: float
    y0: float
    width: int
    height: int

    def pixel(self, x: float, y: float) -> tuple[float, float]:
        """Canvas coordinates (px, from the top-left corner) of world point (x, y) in metres."""
        return (self.x0 + self.scale * x, self.y0 - self.scale * y)


@dataclass(frozen=True, eq=False)
class Plan:
    """One planned horizon a robot's controller sent at `t_sent`: samples ``(t, x, y)``.

    It holds until the next plan of the same robot.
    """

    t_sent: float
    samples: np.ndarray  # shape (n, 3): t, x, y


def view_transform(
    bounds: tuple[float, float, float, float],
    *,
    width: int = 1000,
    height: int = 700,
    margin: int = VIEW_MARGIN_PX,
) -> View:
    """Fit a floor's `bounds` ``(xmin, ymin, xmax, ymax)`` into `width` x `height` pixels.

    The floor keeps its aspect (one scale for both axes) with `margin` pixels on every side; the
    canvas is shrunk to the fitted floor, so one of its sides equals the given size and the
    other may be smaller. y points up in the world and down on the canvas. The page computes
    the same map (``viewTransform`` in ``replay_page/replay.js``) for the area its window leaves
    the canvas; keep the two alike.

    Raises
    ------
    ValueError
        The bounds are empty or not finite, or the size leaves no room inside the margin.
    """
    xmin, ymin, xmax, ymax = (float(v) for v in bounds)
    w, h = xmax - xmin, ymax - ymin
    if not (math.isfinite(w) and math.isfinite(h) and w > 0 and h > 0):
        raise ValueError(f"floor bounds {bounds!r} must be finite with xmax > xmin, ymax > ymin")
    if width <= 2 * margin or height <= 2 * margin:
        raise ValueError(f"canvas {width}x{height} px leaves no room inside a {margin} px margin")
    scale = min((width - 2 * margin) / w, (height - 2 * margin) / h)
    return View(
        scale=scale,
        x0=margin - scale * xmin,
        y0=margin + scale * ymax,
        width=min(width, math.ceil(scale * w + 2 * margin)),
        height=min(height, math.ceil(scale * h + 2 * margin)),
    )


def robot_colour(index: int) -> str:
    """The colour of the `index`-th robot (id order): `ROBOT_COLOURS`, then darker rounds."""
    base = ROBOT_COLOURS[index % len(ROBOT_COLOURS)]
    rounds = index // len(ROBOT_COLOURS)
    if rounds == 0:
        return base
    shade = 0.75**rounds  # a second round darker still keeps ids apart
    rgb = [round(int(base[i : i + 2], 16) * shade) for i in (1, 3, 5)]
    return "#" + "".join(f"{c:02x}" for c in rgb)


def simplify(t: np.ndarray, xy: np.ndarray, tolerance_m: float = 0.01) -> np.ndarray:
    """Indices of the samples to keep so linear interpolation in time stays within tolerance.

    Douglas-Peucker in time: between two kept samples, every dropped sample ``k`` lies within
    `tolerance_m` (Euclidean) of the point interpolated at ``t[k]``. The first and last samples
    are always kept; a robot standing still or driving at constant velocity needs two.

    Parameters
    ----------
    t:
        Sample times, shape (n,), non-decreasing.
    xy:
        Positions, shape (n, 2).
    tolerance_m:
        Largest allowed deviation (m), >= 0.

    Returns
    -------
    numpy.ndarray
        Sorted indices into `t`.
    """
    t = np.asarray(t, dtype=float)
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    n = len(t)
    if n <= 2:
        return np.arange(n)
    keep = np.zeros(n, dtype=bool)
    keep[0] = keep[-1] = True
    stack = [(0, n - 1)]
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            continue
        span = t[j] - t[i]
        inner = slice(i + 1, j)
        if span > 0:
            f = ((t[inner] - t[i]) / span)[:, None]
            err = np.hypot(*(xy[inner] - (xy[i] + f * (xy[j] - xy[i]))).T)
        else:  # samples at one instant: only the last one is drawn, keep them all
            err = np.full(j - i - 1, np.inf)
        worst = int(np.argmax(err))
        if err[worst] > tolerance_m:
            k = i + 1 + worst
            keep[k] = True
            stack += [(i, k), (k, j)]
    return np.flatnonzero(keep)


def load_plans(path: Path) -> dict[str, list[Plan]]:
    """Read ``plans.csv``: robot id -> its plans in the order sent; an absent file: no plans.

    Rows of one plan share ``(robot, t_sent)`` and are ordered by ``k``.

    Raises
    ------
    InputError
        A column is missing or a value is not a number.
    """
    path = Path(path)
    if not path.is_file():
        return {}
    grouped: dict[tuple[str, float], list[tuple[float, float, float, float]]] = {}
    for line, row in read_csv_rows(path, _PLAN_COLUMNS):
        sent, k, t, x, y = (
            csv_number(path, line, col, row[col], finite=True)
            for col in ("t_sent", "k", "t", "x", "y")
        )
        grouped.setdefault((row["robot"], sent), []).append((k, t, x, y))
    plans: dict[str, list[Plan]] = {}
    for (robot, sent), rows in sorted(grouped.items()):
        rows.sort()
        plans.setdefault(robot, []).append(Plan(sent, np.asarray(rows, dtype=float)[:, 1:]))
    return plans


def replay_data(
    run: RunData,
    plans: Mapping[str, Sequence[Plan]] | None = None,
    *,
    tolerance_m: float = 0.01,
) -> dict[str, Any]:
    """The JSON document the replay page embeds (plain lists and numbers only).

    Keys: ``title``, ``t0``, ``t1`` (time range, s), ``bounds`` (the floor's ``[xmin, ymin,
    xmax, ymax]``, m) and ``margin`` (px) that the page fits into its window, ``floor``
    (``boundary``, ``free``, ``zones`` [{``label``, ``colour``, ``polys``}], ``obstacles``,
    ``rough``, ``stations`` [{``name``, ``kind``, ``x``, ``y``}], ``clearance``; polygons are
    lists of rings, a ring a flat ``[x0, y0, x1, y1, ...]`` list), ``kinds`` (kind -> colour),
    ``v_max`` (m/s, for the velocity tick), ``robots`` [{``id``, ``colour``, ``radius``, ``t``,
    ``x``, ``y``, ``plans`` {``sent``, ``pts``}, ``tasks`` [[start, end, kind, job, attempt,
    scrapped]]}], ``jobs`` [{``id``, ``part``, ``station``, ``robot``, ``released``,
    ``assigned``, ``arrived``, ``print_end``, ``delivered``, ``due``, ``outcome``}] (None: not
    happened), ``attempts`` [{``job``, ``attempt``, ``robot``, ``assigned``, ``ended``,
    ``result``, ``reason``, ``printed``, ``scrapped``}] (every robot's try at a job, from
    ``attempts.csv``; empty for a run written without it) and ``handback_mark_s``; with
    ``[battery]`` each robot also has ``battery`` {``t``, ``charge``, ``state``} (battery.csv).
    """
    floor = run.floor
    view_transform(floor.bounds)  # bad bounds fail here, with a message, not in the browser
    spec = floor.spec
    colours = zone_colours(floor)
    by_limit: dict[tuple[float, float], list[BaseGeometry]] = {}
    for r in floor.regions:
        by_limit.setdefault(r.v_max, []).append(r.polygon)
    default = tuple(spec.default_v_max)
    zones = [
        {
            "label": zone_label(limit) + (" (default)" if limit == default else ""),
            "colour": colour,
            "polys": _polys(shapely.union_all(by_limit[limit])),
        }
        for limit, colour in colours.items()
    ]

    radius = _radius(run)
    plans = plans or {}
    robots = []
    for i, (rid, track) in enumerate(run.tracks.items()):
        keep = simplify(track.t, track.xy, tolerance_m)
        mine = plans.get(rid, ())
        robots.append(
            {
                "id": rid,
                "colour": robot_colour(i),
                "radius": radius.get(rid, DEFAULT_RADIUS_M),
                "t": _round(track.t[keep], 3),
                "x": _round(track.xy[keep, 0], 3),
                "y": _round(track.xy[keep, 1], 3),
                "plans": {
                    "sent": [round(p.t_sent, 3) for p in mine],
                    "pts": [_round(p.samples.reshape(-1), 2) for p in mine],
                },
                "tasks": [
                    [round(k.start_s, 3), round(k.end_s, 3), k.kind, k.job, k.attempt, k.scrapped]
                    for k in run.tasks
                    if k.robot == rid
                ],
                "broken": _broken(run, rid),
            }
        )

    battery = _battery(run.run_dir / "battery.csv")
    for robot in robots:  # [battery]: charge and state over time, for the side panel
        if robot["id"] in battery:
            robot["battery"] = battery[robot["id"]]

    times = [float(tr.t[0]) for tr in run.tracks.values() if len(tr.t)]
    v_max = max((max(r.v_max) for r in floor.regions), default=1.0)
    return {
        "title": run.title,
        "t0": min(times, default=0.0),
        "t1": max(run.t_end, min(times, default=0.0)),
        "bounds": [float(v) for v in floor.bounds],
        "margin": VIEW_MARGIN_PX,
        "floor": {
            "boundary": _polys(spec.boundary),
            "free": _polys(floor.free_space),
            "zones": zones,
            "obstacles": [p for o in spec.obstacles for p in _polys(o.polygon)],
            "rough": [p for a in spec.rough_areas for p in _polys(a.polygon)],
            "stations": [
                {"name": s.name, "kind": s.kind, "x": s.x, "y": s.y} for s in spec.stations
            ],
            "clearance": spec.clearance,
            "colours": {
                "obstacle": _OBSTACLE_COLOUR,
                "clearance": _CLEARANCE_COLOUR,
                "station": _STATION_COLOUR,
            },
        },
        "kinds": dict(KIND_COLOURS),
        "v_max": v_max,
        "robots": robots,
        "jobs": _jobs(run),
        "attempts": [
            {
                "job": a.job,
                "attempt": a.attempt,
                "robot": a.robot,
                "assigned": a.assigned_s,
                "ended": a.ended_s,
                "result": a.result,
                "reason": a.reason,
                "printed": round(a.printed_s, 3),
                "scrapped": a.scrapped,
            }
            for a in run.attempts
        ],
        "handback_mark_s": HANDBACK_MARK_S,
    }


def replay_html(data: Mapping[str, Any]) -> str:
    """The replay page for `data` (`replay_data`): one HTML document, no external resources."""
    # Escaping <, > and & keeps any string in the data from closing the script element.
    payload = (
        json.dumps(data, separators=(",", ":"), allow_nan=False)
        .replace("<", "\\u003c")
        .replace(">", "\\u003e")
        .replace("&", "\\u0026")
    )
    slots = {
        "TITLE": html.escape(str(data["title"])),
        "CSS": page_part("replay.css"),
        "SCRIPT": page_part("replay.js"),
        "DATA": payload,
    }
    # One pass: text put into a slot is never searched for slots again.
    return _SLOTS.sub(lambda m: slots[m.group(1)], page_part("replay.html"))


def page_part(name: str) -> str:
    """The text of one of the page's files (package data in ``fleet/view/replay_page``)."""
    return resources.files("fleet.view").joinpath(_PAGE_DIR, name).read_text(encoding="utf-8")


def write_replay(
    run_dir: Path,
    out: Path | None = None,
    *,
    floor: Floor | None = None,
    tolerance_m: float = 0.01,
) -> Path:
    """Write the HTML replay of the run in `run_dir`.

    Parameters
    ----------
    run_dir:
        A run directory written by `fleet run`: ``trajectories.csv`` and (unless `floor` is
        given) ``summary.json`` required; ``plans.csv``, ``tasks.csv`` (else ``caps.csv``),
        ``events.csv``, ``jobs.csv`` and ``attempts.csv`` used when present.
    out:
        The HTML file to write; None: ``run_dir / "replay.html"``.
    floor:
        The run's floor; None loads the map named in ``summary.json``.
    tolerance_m:
        How far (m) the page's interpolated positions may stray from the recorded samples
        (see `simplify`); larger values make smaller files.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    InputError
        A file of the run directory is missing or malformed (see `fleet.view.figures.load_run`,
        `load_plans`).
    """
    run = load_run(Path(run_dir), floor)
    plans = load_plans(run.run_dir / "plans.csv")
    target = Path(out) if out is not None else run.run_dir / REPLAY_HTML
    page = replay_html(replay_data(run, plans, tolerance_m=tolerance_m))
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(page, encoding="utf-8")
    return target


# -- helpers ----------------------------------------------------------------------------------
def _round(a: np.ndarray, digits: int) -> list[float]:
    return np.round(np.asarray(a, dtype=float), digits).tolist()


def _polys(geom: BaseGeometry) -> list[list[list[float]]]:
    """Polygons of `geom` as lists of rings, each a flat [x0, y0, ...] without the closing point."""
    out = []
    for poly in shapely.get_parts(geom):
        if poly.geom_type != "Polygon" or poly.is_empty:
            continue  # a union may leave slivers of lower dimension: nothing to fill
        rings = [poly.exterior, *poly.interiors]
        out.append([_round(np.asarray(r.coords)[:-1].reshape(-1), 3) for r in rings])
    return out


def _radius(run: RunData) -> dict[str, float]:
    """Each robot's radius (m): ``per_robot[].radius_m`` in the summary, else the map's
    clearance (the footprint radius the floor was built for), else `DEFAULT_RADIUS_M`."""
    fallback = run.floor.spec.clearance if run.floor.spec.clearance > 0 else DEFAULT_RADIUS_M
    radius = dict.fromkeys(run.tracks, float(fallback))
    for entry in run.summary.get("per_robot") or ():
        if (
            isinstance(entry, dict)
            and isinstance(entry.get("radius_m"), int | float)
            and entry["radius_m"] > 0
            and entry.get("id") in radius
        ):
            radius[entry["id"]] = float(entry["radius_m"])
    return radius


def _broken(run: RunData, robot: str) -> list[list[float | None]]:
    """When `robot` was broken down (``breakdown`` to ``repaired`` events; None: not repaired
    by the end of the run), as ``[start, end]`` pairs for the page."""
    spans: list[list[float | None]] = []
    for e in run.events:
        if e.robot != robot:
            continue
        if e.event == "breakdown":
            spans.append([round(e.t, 3), None])
        elif e.event == "repaired" and spans and spans[-1][1] is None:
            spans[-1][1] = round(e.t, 3)
    return spans


def _battery(path: Path) -> dict[str, dict[str, list[Any]]]:
    """battery.csv by robot: ``{t, charge, state}`` lists (absent file: no batteries)."""
    out: dict[str, dict[str, list[Any]]] = {}
    if not path.is_file():
        return out
    for line, row in read_csv_rows(path, ("t", "robot", "charge", "state")):
        mine = out.setdefault(row["robot"], {"t": [], "charge": [], "state": []})
        mine["t"].append(round(csv_number(path, line, "t", row["t"], finite=True), 3))
        mine["charge"].append(
            round(csv_number(path, line, "charge", row["charge"], finite=True), 4)
        )
        mine["state"].append(row["state"])
    return out


def _jobs(run: RunData) -> list[dict[str, Any]]:
    """Each job's story for the page, from jobs.csv and events.csv (either may be missing)."""
    story: dict[str, dict[str, Any]] = {}

    def entry(job: str) -> dict[str, Any]:
        return story.setdefault(
            job,
            {
                "id": job,
                "part": None,
                "station": None,
                "robot": None,
                "released": None,
                "assigned": None,
                "arrived": None,
                "print_end": None,
                "delivered": None,
                "due": None,
                "outcome": None,
            },
        )

    for e in run.events:
        if not e.job:
            continue  # a robot's own event (an idle turn), no job's
        j = entry(e.job)
        if e.station and j["station"] is None:
            j["station"] = e.station
        if e.event == "released":
            j["released"] = e.t
        elif e.event == "assigned":
            j["assigned"], j["robot"] = e.t, e.robot or j["robot"]
            j["station"] = e.station or j["station"]
        elif e.event == "arrived":
            j["arrived"] = e.t
        elif e.event == "delivered":
            j["delivered"] = e.t
    for row in run.jobs:
        j = entry(row.id)
        j["part"] = row.part
        j["robot"] = row.robot or j["robot"]
        j["due"] = row.due_s
        j["outcome"] = row.outcome
        for key, value in (("released", row.released_s), ("delivered", row.delivered_s)):
            if j[key] is None:
                j[key] = value
        if j["assigned"] is None and j["robot"] is not None:
            # Without events.csv: the job was in hand from its start at the latest.
            j["assigned"] = row.started_s if row.started_s is not None else row.released_s
        if row.finished_s is not None:
            j["print_end"] = row.finished_s
    for task in run.tasks:
        j = entry(task.job)
        j["print_end"] = max(j["print_end"] or task.end_s, task.end_s)
        j["robot"] = j["robot"] or task.robot
    return sorted(story.values(), key=lambda j: (j["released"] is None, j["released"], j["id"]))
