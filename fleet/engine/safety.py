"""The safety checker: judges a simulated trajectory against the floor, never trusting a controller.

Semantics (the same everywhere in the project): between samples k and k+1 a robot moves on the
straight segment ``p[k] -> p[k+1]`` at the recorded velocity ``v[k]``.

- **obstacle**: the segment (or, for a robot at rest, the point) leaves the free space, i.e. the
  configuration space of the floor, by more than `tol` metres of length.
- **speed_zone**: ``|v[k].x|`` or ``|v[k].y|`` exceeds the per-axis limit of some region that the
  segment enters (a step that straddles a boundary into a slower zone must already be slow;
  touching a boundary at one point, or dipping less than `LENGTH_TOL` into a region, does not
  count; a step running along a shared boundary is bound by the regions on both sides).
- **print_speed**: ``|v[k].x|`` or ``|v[k].y|`` exceeds the cap of a print task that overlaps the
  step's interval ``[t[k], t[k+1])`` (`fleet.printing.CapSchedule`).
- **collision**: two robots closer than the sum of their radii at any time both are recorded,
  between samples too (each moves in a straight line from one of its samples to the next, so
  robots with different control periods are compared too); one violation per pair and contact
  episode.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import shapely
from scipy.spatial import cKDTree

from fleet.floor import BOUNDARY_BAND, Floor
from fleet.printing import CapSchedule

__all__ = [
    "Violation",
    "SafetyReport",
    "check_steps",
    "check_print_speed",
    "check_collisions",
    "SafetyChecker",
]

#: Length (m) of leaving the free space below which rounding is forgiven, and the depth a step
#: must reach inside a region to be bound by it alone (the planner's band, so the two agree).
LENGTH_TOL = BOUNDARY_BAND
#: Speed (m/s) above a limit below which rounding is forgiven.
SPEED_TOL = 1e-6


@dataclass(frozen=True)
class Violation:
    """One broken rule at one step."""

    kind: str  # "obstacle", "speed_zone", "print_speed" or "collision"
    robot: str
    t: float
    x: float
    y: float
    detail: str


@dataclass
class SafetyReport:
    """Counts per kind plus the first violations in full (for the run directory)."""

    counts: dict[str, int] = field(
        default_factory=lambda: {"obstacle": 0, "speed_zone": 0, "print_speed": 0, "collision": 0}
    )
    examples: list[Violation] = field(default_factory=list)
    max_examples: int = 100

    def add(self, violations: Sequence[Violation]) -> None:
        for v in violations:
            self.counts[v.kind] = self.counts.get(v.kind, 0) + 1
            if len(self.examples) < self.max_examples:
                self.examples.append(v)

    @property
    def total(self) -> int:
        return sum(self.counts.values())


def check_steps(
    floor: Floor,
    t: np.ndarray,
    xy: np.ndarray,
    v: np.ndarray,
    robot: str = "",
) -> list[Violation]:
    """Obstacle and zone-speed violations of one robot's trajectory.

    Parameters
    ----------
    t, xy, v:
        Sample times (n,), positions (n, 2) and velocities (n, 2); step k runs from sample k to
        sample k+1 at velocity v[k]. The last sample is checked as a point.
    """
    t = np.asarray(t, dtype=float)
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    v = np.asarray(v, dtype=float).reshape(-1, 2)
    n = len(xy)
    if n == 0:
        return []
    out: list[Violation] = []
    start = xy[:-1]
    end = xy[1:]
    moving = np.any(start != end, axis=1)

    # Points: every sample must be in the free space (catches a robot parked in an obstacle).
    pts = shapely.points(xy)
    inside = shapely.dwithin(floor.free_space, pts, LENGTH_TOL)
    for k in np.flatnonzero(~inside):
        out.append(_v("obstacle", robot, t, xy, k, "position outside the free space"))

    # Segments: covered by the free space (grown by the tolerance, so a step running along an
    # obstacle's face a rounding error inside it passes), else measure how much lies outside.
    seg_idx = np.flatnonzero(moving)
    if len(seg_idx):
        lines = shapely.linestrings(np.stack([start[seg_idx], end[seg_idx]], axis=1))
        covered = shapely.covers(floor.free_space_tolerant, lines)
        for j in np.flatnonzero(~covered):
            outside = shapely.difference(lines[j], floor.free_space).length
            k = int(seg_idx[j])
            if outside > LENGTH_TOL and inside[k] and inside[k + 1]:
                out.append(
                    _v("obstacle", robot, t, xy, k, f"step crosses an obstacle for {outside:.3g} m")
                )
        out.extend(_speed_violations(floor, t, xy, v, seg_idx, lines, robot))
    return sorted(out, key=lambda e: (e.t, e.kind))


def _speed_violations(floor, t, xy, v, seg_idx, lines, robot) -> list[Violation]:
    vmax = np.array([r.v_max for r in floor.regions], dtype=float)
    limit = np.full((len(lines), 2), np.inf)
    # A step is bound by every region it enters deeper than LENGTH_TOL: its overlap with the
    # region's core (the region shrunk by LENGTH_TOL). Measuring depth, not length, forgives a
    # step that runs nearly parallel to a boundary a rounding error on the wrong side of it.
    cores = floor.region_cores(LENGTH_TOL)
    line_i, reg_i = floor.tree.query(lines, predicate="intersects")
    hit = shapely.intersects(lines[line_i], cores[reg_i])
    np.minimum.at(limit, line_i[hit], vmax[reg_i[hit]])
    # A step along a shared boundary enters no core: it is bound by the regions on both sides.
    edge = np.flatnonzero(np.isinf(limit[:, 0]))
    if len(edge):
        polys = np.array([r.polygon for r in floor.regions], dtype=object)
        pick = np.isin(line_i, edge)
        li, ri = line_i[pick], reg_i[pick]
        overlap = shapely.length(shapely.intersection(lines[li], polys[ri])) > LENGTH_TOL
        np.minimum.at(limit, li[overlap], vmax[ri[overlap]])
    speed = np.abs(v[seg_idx])
    bad = np.flatnonzero(np.any(speed > limit + SPEED_TOL, axis=1))
    out = []
    for j in bad:
        k = int(seg_idx[j])
        out.append(
            _v(
                "speed_zone",
                robot,
                t,
                xy,
                k,
                f"|v| = ({speed[j, 0]:.4g}, {speed[j, 1]:.4g}) m/s over limit "
                f"({limit[j, 0]:.4g}, {limit[j, 1]:.4g}) m/s",
            )
        )
    return out


def check_print_speed(
    t: np.ndarray, xy: np.ndarray, v: np.ndarray, caps: CapSchedule, robot: str = ""
) -> list[Violation]:
    """Steps whose per-axis speed exceeds a print cap overlapping ``[t[k], t[k+1])``."""
    if not caps:
        return []
    t = np.asarray(t, dtype=float)
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    speed = np.abs(np.asarray(v, dtype=float).reshape(-1, 2))
    out = []
    for k in range(len(t) - 1):
        # Shrink the interval by a rounding error so a piece ending exactly at t[k] (or
        # starting at t[k+1]) does not bind the step.
        eps = 1e-9 * max(1.0, abs(t[k + 1]))
        cap = caps.cap_over(t[k] + eps, t[k + 1] - eps)
        if speed[k, 0] > cap + SPEED_TOL or speed[k, 1] > cap + SPEED_TOL:
            out.append(
                _v(
                    "print_speed",
                    robot,
                    t,
                    xy,
                    k,
                    f"|v| = ({speed[k, 0]:.4g}, {speed[k, 1]:.4g}) m/s over print cap {cap:.4g}",
                )
            )
    return out


def check_collisions(
    t: np.ndarray,
    robot_index: np.ndarray,
    xy: np.ndarray,
    radii: Sequence[float],
    names: Sequence[str],
) -> list[Violation]:
    """Pairs of robots closer than the sum of their radii at any time both are recorded, between
    their samples too.

    Each robot moves in a straight line at constant velocity from one of its samples to the
    next, so on the union of two robots' sample times (robots with different control periods
    sample at different times) their offset moves in a straight line too, and its nearest
    approach on each interval is exact: two robots that pass through each other between
    samples are caught, however their samples fall. Rows (t, robot_index, xy) may come in any
    order. One violation per pair and contact episode (contact that lasts across a sample
    counts once), reported where the pair comes closest within the episode's first interval.
    """
    t = np.asarray(t, dtype=float)
    robot_index = np.asarray(robot_index, dtype=np.int64)
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    if len(t) == 0:
        return []
    radii_arr = np.asarray(radii, dtype=float)
    order = np.lexsort((t, robot_index))
    t, robot_index, xy = t[order], robot_index[order], xy[order]
    robots = np.unique(robot_index)
    bounds = np.searchsorted(robot_index, robots)
    ends = np.r_[bounds[1:], len(t)]
    tracks = {
        int(r): (t[a:b], xy[a:b]) for r, a, b in zip(robots, bounds, ends, strict=True) if b > a
    }
    out: list[Violation] = []
    for i, j in _candidate_pairs(tracks, radii_arr):
        limit = radii_arr[i] + radii_arr[j] - 1e-9
        for when, d, p in _contacts(*tracks[i], *tracks[j], limit):
            detail = f"{names[i]} and {names[j]} {d:.3f} m apart"
            out.append(Violation("collision", names[i], when, p[0], p[1], detail))
    out.sort(key=lambda v: (v.t, v.robot, v.detail))
    return out


#: Length (s) of the time windows in which `_candidate_pairs` boxes each robot's track.
WINDOW_S = 2.0


def _candidate_pairs(
    tracks: Mapping[int, tuple[np.ndarray, np.ndarray]], radii: np.ndarray
) -> list[tuple[int, int]]:
    """Pairs (i < j) of robots whose tracks could come within their radii: per time window of
    `WINDOW_S`, the box round each track's samples there and the first one after (so it holds
    every segment that starts in the window), and the pairs whose boxes, grown by the largest
    radius sum, overlap in some window (a k-d tree over box centres finds them in large
    fleets)."""
    keys, los, his, who = [], [], [], []
    for r, (t, p) in tracks.items():
        window = np.floor(t / WINDOW_S).astype(np.int64)
        cross = np.flatnonzero(np.diff(window) != 0)  # segments that end in the next window
        w = np.r_[window, window[cross]]
        q = np.vstack([p, p[cross + 1]])
        order = np.argsort(w, kind="stable")
        w, q = w[order], q[order]
        starts = np.flatnonzero(np.r_[True, np.diff(w) != 0])
        keys.append(w[starts])
        los.append(np.minimum.reduceat(q, starts, axis=0))
        his.append(np.maximum.reduceat(q, starts, axis=0))
        who.append(np.full(len(starts), r))
    if not keys:
        return []
    key, lo, hi, rid = (np.concatenate(x) for x in (keys, los, his, who))
    reach = 2.0 * float(radii.max())
    pairs: set[tuple[int, int]] = set()
    order = np.argsort(key, kind="stable")
    key, lo, hi, rid = key[order], lo[order], hi[order], rid[order]
    bounds = np.flatnonzero(np.r_[True, np.diff(key) != 0, True])
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        if b - a < 2:
            continue
        centre, half = (lo[a:b] + hi[a:b]) / 2, (hi[a:b] - lo[a:b]) / 2
        # Boxes meet (grown by `reach`) only if their centres are this close on each axis.
        limit = float(np.max(half)) * 2.0 + reach
        near = cKDTree(centre).query_pairs(limit * np.sqrt(2.0), output_type="ndarray")
        if len(near) == 0:
            continue
        x, y = near[:, 0], near[:, 1]
        gap = np.abs(centre[x] - centre[y]) - half[x] - half[y]
        meet = np.all(gap < reach, axis=1)
        for u, v in zip(rid[a:b][x[meet]], rid[a:b][y[meet]], strict=True):
            pairs.add((int(min(u, v)), int(max(u, v))))
    return sorted(pairs)


def _contacts(
    t1: np.ndarray, p1: np.ndarray, t2: np.ndarray, p2: np.ndarray, limit: float
) -> list[tuple[float, float, tuple[float, float]]]:
    """The contact episodes of two tracks (sample times, positions): per episode the time and
    distance of the closest approach in its first interval, and where the first robot is then.
    """
    if np.array_equal(t1, t2):
        times, a, b = t1, p1, p2
    else:
        start, end = max(t1[0], t2[0]), min(t1[-1], t2[-1])
        if start > end:
            return []  # never recorded at the same time
        times = np.union1d(t1, t2)
        times = times[(times >= start) & (times <= end)]
        a = np.column_stack([np.interp(times, t1, p1[:, 0]), np.interp(times, t1, p1[:, 1])])
        b = np.column_stack([np.interp(times, t2, p2[:, 0]), np.interp(times, t2, p2[:, 1])])
    d = a - b
    at_samples = np.hypot(d[:, 0], d[:, 1])
    if len(times) == 1:
        if at_samples[0] >= limit:
            return []
        return [(float(times[0]), float(at_samples[0]), (float(a[0, 0]), float(a[0, 1])))]
    step = np.diff(d, axis=0)
    length2 = np.einsum("ij,ij->i", step, step)
    s = np.divide(
        -np.einsum("ij,ij->i", d[:-1], step), length2, out=np.zeros_like(length2), where=length2 > 0
    )
    s = np.clip(s, 0.0, 1.0)
    nearest = d[:-1] + s[:, None] * step
    closest = np.hypot(nearest[:, 0], nearest[:, 1])
    touching = closest < limit
    # An episode goes on into the next interval only if the pair is in contact at the sample
    # between them (the distance within an interval is convex: one stretch of contact each).
    goes_on = np.r_[False, touching[:-1] & (at_samples[1:-1] < limit)]
    out = []
    for k in np.flatnonzero(touching & ~goes_on):
        when = times[k] + s[k] * (times[k + 1] - times[k])
        where = a[k] + s[k] * (a[k + 1] - a[k])
        out.append((float(when), float(closest[k]), (float(where[0]), float(where[1]))))
    return out


class SafetyChecker:
    """Checks whole runs: per-robot steps against the floor, then robot pairs."""

    def __init__(self, floor: Floor) -> None:
        self.floor = floor

    def check(
        self,
        trajectories: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
        radii: Mapping[str, float],
        caps: Mapping[str, CapSchedule] | None = None,
    ) -> SafetyReport:
        """`trajectories[robot] = (t, xy, v)`; `caps[robot]` the print caps it was under.

        Returns counts and the first violations.
        """
        report = SafetyReport()
        names = sorted(trajectories)
        for name in names:
            t, xy, v = trajectories[name]
            report.add(check_steps(self.floor, t, xy, v, name))
            if caps and name in caps:
                report.add(check_print_speed(t, xy, v, caps[name], name))
        if len(names) > 1:
            ts, idx, pts = [], [], []
            for i, name in enumerate(names):
                t, xy, _ = trajectories[name]
                ts.append(t)
                idx.append(np.full(len(t), i))
                pts.append(xy)
            report.add(
                check_collisions(
                    np.concatenate(ts),
                    np.concatenate(idx),
                    np.concatenate(pts),
                    [radii[n] for n in names],
                    names,
                )
            )
        return report


def _v(kind: str, robot: str, t: np.ndarray, xy: np.ndarray, k: int, detail: str) -> Violation:
    return Violation(kind, robot, float(t[k]), float(xy[k, 0]), float(xy[k, 1]), detail)
