"""The HTML replay of a finished run: one self-contained file that animates the fleet.

`write_replay` reads a run directory (never re-running anything) and writes one HTML file with
inline CSS and JavaScript and the run's data embedded as JSON (``<script
type="application/json" id="replay-data">``). It needs no server and fetches nothing: no URL
appears in the page, so it works offline and from ``file://``.

The page draws the floor on a canvas (speed zones in the colours of
`fleet.view.figures.zone_colours`, obstacles, the clearance band, rough floor, labelled stations),
each robot as a filled circle of its radius in its own colour with a velocity tick, its planned
horizon (``plans.csv``) as a thin dashed line, and its job state (idle, to station, printing,
arrived and waiting for the print) as a ring and a label. A side panel holds the legend, the robots
and the jobs (open, assigned, delivered with the outcome). Controls: a time slider, play/pause, a
speed select (1x, 10x, 60x) and the current time.

Seeking is scriptable: the page reads ``#t=SECONDS`` from its URL at load and on every hash
change, and exposes ``window.replaySeek(t)``.

Geometry is deterministic so tests can check pixels: the canvas sits at the page's top-left
corner (body margin 0) at its pixel size (no CSS scaling), and `view_transform` gives the
world-to-pixel map the page uses. Positions between two embedded samples are interpolated
linearly; samples are thinned by `simplify` so that this interpolation stays within a
tolerance (1 cm by default) of every recorded sample.
"""

from __future__ import annotations

import html
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
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
    "View",
    "Plan",
    "view_transform",
    "robot_colour",
    "simplify",
    "load_plans",
    "replay_data",
    "replay_html",
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

_PLAN_COLUMNS = ("t_sent", "robot", "k", "t", "x", "y")
_OBSTACLE_COLOUR = "#6b0f0f"
_CLEARANCE_COLOUR = "#cfcfcf"
_STATION_COLOUR = "#1f3b73"


@dataclass(frozen=True)
class View:
    """The page's world-to-canvas map: pixel ``(x0 + scale * x, y0 - scale * y)``.

    Canvas pixel ``(col, row)`` covers ``[col, col + 1) x [row, row + 1)`` of that map; the
    canvas is `width` x `height` pixels at the page's top-left corner.
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
    margin: int = 20,
) -> View:
    """Fit a floor's `bounds` ``(xmin, ymin, xmax, ymax)`` into `width` x `height` pixels.

    The floor keeps its aspect (one scale for both axes) with `margin` pixels on every side; the
    canvas is shrunk to the fitted floor, so one of its sides equals the given size and the
    other may be smaller. y points up in the world and down on the canvas.

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

    Keys: ``title``, ``t0``, ``t1`` (time range, s), ``view`` (`View` fields), ``floor``
    (``boundary``, ``free``, ``zones`` [{``label``, ``colour``, ``polys``}], ``obstacles``,
    ``rough``, ``stations`` [{``name``, ``kind``, ``x``, ``y``}], ``clearance``; polygons are
    lists of rings, a ring a flat ``[x0, y0, x1, y1, ...]`` list), ``kinds`` (kind -> colour),
    ``v_max`` (m/s, for the velocity tick), ``robots`` [{``id``, ``colour``, ``radius``, ``t``,
    ``x``, ``y``, ``plans`` {``sent``, ``pts``}, ``tasks`` [[start, end, kind, job]]}] and
    ``jobs`` [{``id``, ``part``, ``station``, ``robot``, ``released``, ``assigned``, ``arrived``,
    ``print_end``, ``delivered``, ``due``, ``outcome``}] (None: not happened).
    """
    floor = run.floor
    view = view_transform(floor.bounds)
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
                    [round(k.start_s, 3), round(k.end_s, 3), k.kind, k.job]
                    for k in run.tasks
                    if k.robot == rid
                ],
            }
        )

    times = [float(tr.t[0]) for tr in run.tracks.values() if len(tr.t)]
    v_max = max((max(r.v_max) for r in floor.regions), default=1.0)
    return {
        "title": run.title,
        "t0": min(times, default=0.0),
        "t1": max(run.t_end, min(times, default=0.0)),
        "view": {
            "scale": view.scale,
            "x0": view.x0,
            "y0": view.y0,
            "width": view.width,
            "height": view.height,
        },
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
    }


def replay_html(data: Mapping[str, Any]) -> str:
    """The replay page for `data` (`replay_data`): one HTML document, no external resources."""
    view = data["view"]
    # Escaping <, > and & keeps any string in the data from closing the script element.
    payload = (
        json.dumps(data, separators=(",", ":"), allow_nan=False)
        .replace("<", "\\u003c")
        .replace(">", "\\u003e")
        .replace("&", "\\u0026")
    )
    return (
        _PAGE.replace("@TITLE@", html.escape(str(data["title"])))
        .replace("@W@", str(view["width"]))
        .replace("@H@", str(view["height"]))
        .replace("@PANEL_X@", str(view["width"] + 12))
        .replace("@DATA@", payload)
        .replace("@SCRIPT@", _SCRIPT)
    )


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
        ``events.csv`` and ``jobs.csv`` used when present.
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


_PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>replay: @TITLE@</title>
<style>
html, body { margin: 0; padding: 0; background: #fff; color: #222;
  font: 12px/1.35 system-ui, -apple-system, "Segoe UI", sans-serif; }
#floor { position: absolute; left: 0; top: 0; display: block;
  width: @W@px; height: @H@px; }
#controls { position: absolute; left: 0; top: @H@px; width: @W@px; box-sizing: border-box;
  padding: 6px 20px; display: flex; gap: 10px; align-items: center; }
#controls input[type=range] { flex: 1; }
#time { font-variant-numeric: tabular-nums; min-width: 11em; }
#side { position: absolute; left: @PANEL_X@px; top: 0; width: 330px; padding: 8px 0;
  box-sizing: border-box; }
#side h1 { font-size: 14px; margin: 0 0 6px; }
#side h2 { font-size: 12px; margin: 10px 0 4px; text-transform: uppercase; color: #555; }
#side ul { list-style: none; margin: 0; padding: 0; }
#side li { margin: 1px 0; }
.sw { display: inline-block; width: 12px; height: 12px; margin-right: 6px;
  vertical-align: -2px; border: 1px solid #999; box-sizing: border-box; }
.dot { border-radius: 50%; border: none; }
table { border-collapse: collapse; width: 100%; }
td, th { text-align: left; padding: 1px 4px; white-space: nowrap; }
th { color: #555; font-weight: 600; }
.st-open { color: #a15c00; } .st-assigned { color: #1f3b73; }
.st-delivered { color: #2a7a2a; } .st-bad { color: #b00000; font-weight: 600; }
</style>
</head>
<body>
<canvas id="floor" width="@W@" height="@H@"></canvas>
<div id="controls">
  <button id="play" type="button">Play</button>
  <input id="slider" type="range" step="any" aria-label="time">
  <span id="time"></span>
  <label>speed <select id="speed">
    <option value="1">1x</option><option value="10" selected>10x</option>
    <option value="60">60x</option></select></label>
</div>
<div id="side">
  <h1 id="title"></h1>
  <h2>Floor</h2><ul id="legend"></ul>
  <h2>Robots</h2><ul id="robots"></ul>
  <h2>Jobs</h2><table><thead><tr><th>job</th><th>part</th><th>to</th><th>robot</th>
  <th>state</th></tr></thead><tbody id="jobs"></tbody></table>
</div>
<script type="application/json" id="replay-data">@DATA@</script>
<script>
@SCRIPT@
</script>
</body>
</html>
"""

_SCRIPT = r"""(function () {
"use strict";
const D = JSON.parse(document.getElementById("replay-data").textContent);
const V = D.view, F = D.floor, C = F.colours;
const canvas = document.getElementById("floor");
const ctx = canvas.getContext("2d");
const slider = document.getElementById("slider");
const playButton = document.getElementById("play");
const speedSelect = document.getElementById("speed");
const timeLabel = document.getElementById("time");
const px = (x) => V.x0 + V.scale * x;
const py = (y) => V.y0 - V.scale * y;

function el(tag, attrs, text) {
  const e = document.createElement(tag);
  for (const k in attrs || {}) e.setAttribute(k, attrs[k]);
  if (text !== undefined) e.textContent = text;
  return e;
}

// -- the floor, drawn once ---------------------------------------------------------------------
function tracePolys(g, polys) {
  g.beginPath();
  for (const rings of polys) {
    for (const ring of rings) {
      for (let i = 0; i < ring.length; i += 2) {
        if (i === 0) g.moveTo(px(ring[i]), py(ring[i + 1]));
        else g.lineTo(px(ring[i]), py(ring[i + 1]));
      }
      g.closePath();
    }
  }
}

function hatch() {
  const p = document.createElement("canvas");
  p.width = p.height = 8;
  const g = p.getContext("2d");
  g.strokeStyle = "rgba(80,80,80,0.7)";
  g.lineWidth = 1;
  g.beginPath(); g.moveTo(0, 8); g.lineTo(8, 0); g.moveTo(-2, 2); g.lineTo(2, -2);
  g.moveTo(6, 10); g.lineTo(10, 6); g.stroke();
  return p;
}

const MARKERS = { depot: "square", delivery: "triangle", charger: "plus" };

function marker(g, kind, x, y, r) {
  g.beginPath();
  const shape = MARKERS[kind] || "diamond";
  if (shape === "square") g.rect(x - r, y - r, 2 * r, 2 * r);
  else if (shape === "triangle") { g.moveTo(x, y - r * 1.2); g.lineTo(x + r * 1.1, y + r * 0.8);
    g.lineTo(x - r * 1.1, y + r * 0.8); g.closePath(); }
  else if (shape === "plus") { const a = r * 0.4; g.moveTo(x - a, y - r); g.lineTo(x + a, y - r);
    g.lineTo(x + a, y - a); g.lineTo(x + r, y - a); g.lineTo(x + r, y + a); g.lineTo(x + a, y + a);
    g.lineTo(x + a, y + r); g.lineTo(x - a, y + r); g.lineTo(x - a, y + a); g.lineTo(x - r, y + a);
    g.lineTo(x - r, y - a); g.lineTo(x - a, y - a); g.closePath(); }
  else { g.moveTo(x, y - r); g.lineTo(x + r, y); g.lineTo(x, y + r); g.lineTo(x - r, y);
    g.closePath(); }
}

function drawFloor(g) {
  g.fillStyle = "#ffffff";
  g.fillRect(0, 0, V.width, V.height);
  // Grey under white free space: what shows grey is the band the robot's centre may not enter.
  tracePolys(g, F.boundary); g.fillStyle = C.clearance; g.fill("evenodd");
  tracePolys(g, F.free); g.fillStyle = "#ffffff"; g.fill("evenodd");
  for (const z of F.zones) { tracePolys(g, z.polys); g.fillStyle = z.colour; g.fill("evenodd"); }
  if (F.rough.length) {
    tracePolys(g, F.rough); g.fillStyle = g.createPattern(hatch(), "repeat"); g.fill("evenodd");
  }
  tracePolys(g, F.obstacles); g.fillStyle = C.obstacle; g.fill("evenodd");
  tracePolys(g, F.boundary); g.strokeStyle = "#000"; g.lineWidth = 1.2; g.stroke();
  g.font = "10px sans-serif"; g.textBaseline = "bottom";
  for (const s of F.stations) {
    const x = px(s.x), y = py(s.y);
    marker(g, s.kind, x, y, 4); g.fillStyle = C.station; g.fill();
    g.strokeStyle = "#fff"; g.lineWidth = 0.8; g.stroke();
    g.fillStyle = C.station; g.fillText(s.name, x + 6, y - 3);
  }
}

const background = document.createElement("canvas");
background.width = V.width; background.height = V.height;
drawFloor(background.getContext("2d"));

// -- where things are at time t ----------------------------------------------------------------
function bisect(a, t) {  // last i with a[i] <= t (-1 if none)
  let lo = 0, hi = a.length;
  while (lo < hi) { const mid = (lo + hi) >> 1; if (a[mid] <= t) lo = mid + 1; else hi = mid; }
  return lo - 1;
}

function positionAt(r, t) {
  const n = r.t.length;
  if (n === 0) return null;
  const i = bisect(r.t, t);
  if (i < 0) return { x: r.x[0], y: r.y[0], vx: 0, vy: 0 };
  if (i >= n - 1) return { x: r.x[n - 1], y: r.y[n - 1], vx: 0, vy: 0 };
  const dt = r.t[i + 1] - r.t[i];
  const f = dt > 0 ? (t - r.t[i]) / dt : 1;
  const vx = dt > 0 ? (r.x[i + 1] - r.x[i]) / dt : 0, vy = dt > 0 ? (r.y[i + 1] - r.y[i]) / dt : 0;
  return { x: r.x[i] + f * (r.x[i + 1] - r.x[i]), y: r.y[i] + f * (r.y[i + 1] - r.y[i]), vx, vy };
}

for (const r of D.robots) {
  r.jobs = D.jobs.filter((j) => j.robot === r.id && j.assigned !== null);
}

function stateAt(r, t) {
  const job = r.jobs.find((j) => j.assigned <= t && (j.delivered === null || t < j.delivered));
  if (!job) return { key: "idle", text: "idle", ring: null };
  const to = job.station || "station";
  const task = r.tasks.find((k) => k[0] <= t && t < k[1]);
  const kind = task ? task[2] : null;
  const kindColour = kind ? (D.kinds[kind] || D.kinds.other) : null;
  if (job.arrived !== null && job.arrived <= t) {
    if (job.print_end !== null && t < job.print_end) {
      const what = kind ? " (" + kind + ")" : "";
      return { key: "waiting", text: "at " + to + ", waiting for print" + what,
        ring: kindColour || "#b8860b" };
    }
    return { key: "arrived", text: "at " + to, ring: "#555555" };
  }
  if (task) return { key: "printing", text: "printing " + kind + ", to " + to, ring: kindColour };
  return { key: "to", text: "to " + to, ring: C.station };
}

function planAt(r, t) {
  const i = bisect(r.plans.sent, t);
  return i < 0 ? null : r.plans.pts[i];
}

// -- drawing a frame ---------------------------------------------------------------------------
function drawFrame(t) {
  ctx.drawImage(background, 0, 0);
  const now = D.robots.map((r) => ({ r, p: positionAt(r, t), s: stateAt(r, t) }));
  // Planned horizons first: robots are drawn over them.
  ctx.lineWidth = 1.5;
  ctx.setLineDash([5, 3]);
  for (const { r, p } of now) {
    const pts = p && planAt(r, t);
    if (!pts) continue;
    ctx.beginPath();
    ctx.moveTo(px(p.x), py(p.y));
    let ahead = 0;
    for (let i = 0; i < pts.length; i += 3) {
      if (pts[i] <= t) continue;  // the part of the plan already lived through
      ctx.lineTo(px(pts[i + 1]), py(pts[i + 2]));
      ahead++;
    }
    if (ahead) { ctx.strokeStyle = r.colour; ctx.stroke(); }
  }
  ctx.setLineDash([]);
  for (const { r, p, s } of now) {
    if (!p) continue;
    const x = px(p.x), y = py(p.y), rad = Math.max(r.radius * V.scale, 4);
    ctx.beginPath(); ctx.arc(x, y, rad, 0, 2 * Math.PI);
    ctx.fillStyle = r.colour; ctx.fill();
    ctx.strokeStyle = "#ffffff"; ctx.lineWidth = 1; ctx.stroke();
    if (s.ring) {
      ctx.beginPath(); ctx.arc(x, y, rad + 2.5, 0, 2 * Math.PI);
      ctx.strokeStyle = s.ring; ctx.lineWidth = 2; ctx.stroke();
    }
    const speed = Math.hypot(p.vx, p.vy);
    if (speed > 1e-3) {  // the velocity tick starts at the rim so the disk keeps its colour
      const ux = p.vx / speed, uy = -p.vy / speed, len = 5 + 12 * Math.min(1, speed / D.v_max);
      ctx.beginPath();
      ctx.moveTo(x + ux * (rad + 3.5), y + uy * (rad + 3.5));
      ctx.lineTo(x + ux * (rad + 3.5 + len), y + uy * (rad + 3.5 + len));
      ctx.strokeStyle = "#111111"; ctx.lineWidth = 2; ctx.stroke();
    }
  }
  ctx.font = "11px sans-serif"; ctx.textBaseline = "bottom"; ctx.lineJoin = "round";
  for (const { r, p, s } of now) {
    if (!p) continue;
    const rad = Math.max(r.radius * V.scale, 4), text = r.id + ": " + s.text;
    let x = px(p.x) + rad + 5;
    const y = py(p.y) - rad - 2;
    const w = ctx.measureText(text).width;
    if (x + w > V.width) x = Math.max(0, px(p.x) - rad - 5 - w);  // near the right edge: left
    ctx.strokeStyle = "rgba(255,255,255,0.85)"; ctx.lineWidth = 3; ctx.strokeText(text, x, y);
    ctx.fillStyle = "#111111"; ctx.fillText(text, x, y);
  }
  return now;
}

// -- the side panel ----------------------------------------------------------------------------
document.getElementById("title").textContent = D.title;
document.title = "replay: " + D.title;
const legend = document.getElementById("legend");
function legendItem(colour, label, round) {
  const li = el("li");
  const sw = el("span", { class: "sw" + (round ? " dot" : "") });
  sw.style.background = colour;
  li.append(sw, document.createTextNode(label));
  legend.append(li);
}
for (const z of F.zones) legendItem(z.colour, "zone " + z.label);
if (F.obstacles.length) legendItem(C.obstacle, "obstacle");
if (F.clearance > 0) legendItem(C.clearance, "clearance (" + F.clearance + " m)");
if (F.rough.length) legendItem("repeating-linear-gradient(135deg,#fff 0 3px,#777 3px 4px)",
  "rough floor");
if (F.stations.length) legendItem(C.station, "station");
for (const k in D.kinds) legendItem(D.kinds[k], "ring: printing " + k, true);
legendItem(C.station, "ring: to station", true);
legendItem("#b8860b", "ring: arrived, waiting for print", true);

const robotList = document.getElementById("robots");
const robotText = D.robots.map((r) => {
  const li = el("li");
  const sw = el("span", { class: "sw dot" });
  sw.style.background = r.colour;
  const text = el("span", {}, "");
  li.append(sw, document.createTextNode(r.id + ": "), text);
  robotList.append(li);
  return text;
});

const jobBody = document.getElementById("jobs");
const jobRows = D.jobs.map((j) => {
  const tr = el("tr");
  const state = el("td");
  tr.append(el("td", {}, j.id), el("td", {}, j.part || "-"), el("td", {}, j.station || "-"),
    el("td", {}, j.robot || "-"), state);
  jobBody.append(tr);
  return { j, tr, state, last: null };
});

function jobState(j, t) {
  if (j.released !== null && t < j.released) return null;
  if (j.assigned === null || t < j.assigned) return ["open", "st-open"];
  if (j.delivered === null || t < j.delivered) return ["assigned", "st-assigned"];
  const late = j.due !== null && j.delivered > j.due ? ", late" : "";
  const bad = (j.outcome && j.outcome !== "good") || late;
  return ["delivered" + (j.outcome ? " (" + j.outcome + late + ")" : late ? " (late)" : ""),
    bad ? "st-bad" : "st-delivered"];
}

function updatePanel(t, now) {
  now.forEach(({ s }, i) => {
    if (robotText[i].textContent !== s.text) robotText[i].textContent = s.text;
  });
  for (const row of jobRows) {
    const st = jobState(row.j, t);
    const key = st ? st.join("|") : "hidden";
    if (key === row.last) continue;  // touch the DOM only when a job changes state
    row.last = key;
    row.tr.style.display = st ? "" : "none";
    if (st) { row.state.textContent = st[0]; row.state.className = st[1]; }
  }
}

// -- time --------------------------------------------------------------------------------------
const FRAME_MS = 33;
let current = D.t0, playing = false, lastStamp = 0, timer = null;
slider.min = D.t0; slider.max = D.t1;

function clock(t) {
  const s = Math.floor(t), h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60);
  const pad = (v) => String(v).padStart(2, "0");
  return "t = " + t.toFixed(2) + " s (" + h + ":" + pad(m) + ":" + pad(s % 60) + ")";
}

function seek(t) {
  t = Number(t);
  if (!isFinite(t)) return current;
  current = Math.min(D.t1, Math.max(D.t0, t));
  slider.value = current;
  timeLabel.textContent = clock(current);
  updatePanel(current, drawFrame(current));
  return current;
}

function setPlaying(on) {
  playing = on && current < D.t1;
  playButton.textContent = playing ? "Pause" : "Play";
  clearTimeout(timer);
  lastStamp = performance.now();
  if (playing) timer = setTimeout(step, FRAME_MS);
}

// A timer rather than requestAnimationFrame: it also runs under a headless browser's virtual
// time, where animation frames may never come.
function step() {
  if (!playing) return;
  const now = performance.now();
  seek(current + (now - lastStamp) / 1000 * Number(speedSelect.value));
  lastStamp = now;
  if (current >= D.t1) { setPlaying(false); return; }
  timer = setTimeout(step, FRAME_MS);
}

function hashTime() {
  const m = /(?:^#|&)t=([-+0-9.eE]+)/.exec(location.hash);
  return m ? Number(m[1]) : null;
}

slider.addEventListener("input", () => seek(slider.value));
playButton.addEventListener("click", () => setPlaying(!playing));
window.addEventListener("hashchange", () => { const t = hashTime(); if (t !== null) seek(t); });
document.addEventListener("keydown", (e) => {
  if (e.key === " " && e.target === document.body) { e.preventDefault(); setPlaying(!playing); }
});
window.replaySeek = seek;
window.replayTime = () => current;
const start = hashTime();
seek(start === null ? D.t0 : start);
})();
"""
