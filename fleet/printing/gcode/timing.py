"""How long each move takes: a Marlin-style planner with trapezoidal acceleration.

The model is the one Marlin's classic planner uses (and PrusaSlicer's and CuraEngine's own
estimators copy), so the total agrees with the slicer's estimate:

1. *Cruise speed.* The move's feedrate ``F`` (mm/min, modal), raised to the minimum feedrate
   (M205 S for extruding moves, T for the rest) and scaled down until no axis exceeds its M203
   maximum feedrate.
2. *Acceleration.* M204 P for extruding moves, R for moves of the extruder alone (retract,
   unretract), T for every other move (M204 S sets P and T); scaled down until no axis exceeds
   its M201 maximum acceleration.
3. *Junction speeds.* A move may start at its *safe speed* (the cruise speed, lowered to an
   axis's jerk when that axis alone would jump by more than its jerk, M205 X/Y/Z/E). Between two
   moves the speed may stay higher: the largest speed at which no axis's velocity changes by more
   than its jerk (with Marlin's rule for an axis that keeps its direction, "coasting", versus one
   that reverses). With M205 J (junction deviation) the speed through an XYZ corner is instead
   ``sqrt(a * J * s / (1 - s))`` with ``s = sin(theta / 2)``, theta the angle between the moves.
4. *Reachability.* A backward pass lowers each entry speed so the move can still brake to the
   next entry speed over its length, then a forward pass lowers it so it can be reached from the
   previous entry speed: every move's entry and exit speed is reachable.
5. *Trapezoid.* Each move accelerates from its entry speed towards its cruise speed, cruises,
   and decelerates to its exit speed (the next move's entry speed); when it is too short to reach
   cruise speed the profile is a triangle.

Dwell (G4) takes its time and the planner empties before it, as Marlin's does. Heating and
waiting for temperature (M109, M190), homing (G28) and probing take no time: a MAMbot prints
from a hot, homed printer, and the slicers' own estimates leave them out too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["MachineLimits", "DEFAULT_LIMITS", "move_times"]


@dataclass(frozen=True, slots=True)
class MachineLimits:
    """The firmware's motion limits in force for a move (Marlin units: mm, s).

    Axes are ordered X, Y, Z, E. A G-code file sets these with M201 (max acceleration), M203
    (max feedrate), M204 (P print, R retract, T travel, S print and travel acceleration) and
    M205 (X/Y/Z/E jerk, J junction deviation, S/T minimum feedrates); PrusaSlicer's
    ``; machine_max_...`` config comments give the starting values when present.
    """

    max_feedrate: tuple[float, float, float, float] = (200.0, 200.0, 12.0, 120.0)
    max_acceleration: tuple[float, float, float, float] = (1000.0, 1000.0, 200.0, 5000.0)
    jerk: tuple[float, float, float, float] = (10.0, 10.0, 0.4, 5.0)
    #: Junction deviation (mm, M205 J); when set it replaces the X/Y/Z jerk at junctions.
    junction_deviation: float | None = None
    print_acceleration: float = 1000.0
    retract_acceleration: float = 1000.0
    travel_acceleration: float = 1000.0
    min_feedrate: float = 0.0
    min_travel_feedrate: float = 0.0


#: Used for whatever a file does not set: a typical Marlin printer (Ender-3-like, close to
#: PrusaSlicer's own defaults): 200 mm/s X/Y, 12 mm/s Z, 120 mm/s E; 1000 mm/s^2 X/Y, 200 Z,
#: 5000 E; print, travel and retract acceleration 1000 mm/s^2; jerk 10 mm/s X/Y, 0.4 Z, 5 E.
DEFAULT_LIMITS = MachineLimits()

# Marlin ignores the previous move in the junction when it was (almost) at rest.
_PREVIOUS_FEEDRATE_THRESHOLD = 1e-4


def move_times(
    delta: np.ndarray,
    length: np.ndarray,
    feed: np.ndarray,
    limits: np.ndarray,
    limit_sets: list[MachineLimits],
    dwell: np.ndarray,
) -> np.ndarray:
    """Seconds each entry of a program takes.

    Parameters
    ----------
    delta:
        (n, 4) displacement X, Y, Z, E of each entry (mm); zeros for a dwell.
    length:
        (n,) path length (mm): the XYZ length, the arc length of G2/G3, ``|E|`` for a move of
        the extruder alone, 0 for a dwell or a move that goes nowhere.
    feed:
        (n,) requested feedrate (mm/s).
    limits:
        (n,) index into `limit_sets` of the limits in force for each entry.
    dwell:
        (n,) seconds of dwell (G4); a dwell empties the planner.

    Returns
    -------
    numpy.ndarray
        (n,) seconds, >= 0; entries with no length and no dwell take 0.
    """
    times = np.array(dwell, dtype=float)
    moving = np.flatnonzero(length > 1e-9)
    if len(moving) == 0:
        return times
    # A dwell (or the start) before a move empties the planner: the move starts from its safe
    # speed and the one before it ends at its own. `after_dwell` counts dwells so far.
    after_dwell = np.cumsum(np.asarray(dwell) > 0)
    fresh = np.ones(len(moving), dtype=bool)
    fresh[1:] = after_dwell[moving[1:]] != after_dwell[moving[:-1]]

    d = np.asarray(delta, dtype=float)[moving]
    dist = np.asarray(length, dtype=float)[moving]
    lim = np.asarray(limits)[moving]
    table = _limit_table(limit_sets)
    max_feed = table["max_feedrate"][lim]
    max_acc = table["max_acceleration"][lim]
    jerk = table["jerk"][lim]
    jd = table["junction_deviation"][lim]

    xyz = np.abs(d[:, :3]).sum(axis=1) > 0
    extruding = (d[:, 3] > 0) & xyz
    e_only = ~xyz
    f = np.asarray(feed, dtype=float)[moving]
    f = np.where(d[:, 3] == 0, np.maximum(f, table["min_travel_feedrate"][lim]), f)
    f = np.where(d[:, 3] != 0, np.maximum(f, table["min_feedrate"][lim]), f)
    f = np.maximum(f, 1e-6)  # F0 would stall the move forever; Marlin clamps too

    # 1. Cruise speed: no axis above its maximum feedrate.
    unit = d / dist[:, None]
    axis_f = f[:, None] * unit
    with np.errstate(divide="ignore"):
        ratio = np.where(np.abs(axis_f) > 0, max_feed / np.abs(axis_f), np.inf)
    factor = np.minimum(1.0, ratio.min(axis=1))
    cruise = f * factor
    axis_f *= factor[:, None]

    # 2. Acceleration: by move type, then no axis above its maximum acceleration.
    acc = np.where(
        extruding,
        table["print_acceleration"][lim],
        np.where(e_only, table["retract_acceleration"][lim], table["travel_acceleration"][lim]),
    )
    comp = np.abs(unit)
    with np.errstate(divide="ignore"):
        acc = np.minimum(acc, np.where(comp > 0, max_acc / comp, np.inf).min(axis=1))
    acc = np.maximum(acc, 1e-6)

    # 3. Safe speed and junction speeds.
    safe = cruise.copy()
    for a in range(4):
        over = np.abs(axis_f[:, a]) > jerk[:, a]
        safe = np.where(over, np.minimum(safe, jerk[:, a]), safe)
    max_entry = safe.copy()
    if len(moving) > 1:
        joined = ~fresh[1:] & (cruise[:-1] > _PREVIOUS_FEEDRATE_THRESHOLD)
        max_entry[1:] = np.where(
            joined,
            _junction_speed(cruise, axis_f, safe, jerk, jd, unit, acc),
            safe[1:],
        )

    # 4. Backward then forward pass (sequential by nature; plain floats are fastest here).
    entry = max_entry.tolist()
    cap = (2.0 * acc * dist).tolist()
    safe_l = safe.tolist()
    fresh_l = fresh.tolist()
    m = len(entry)
    exit_ = [0.0] * m
    for i in range(m - 1, -1, -1):
        nxt = entry[i + 1] if i + 1 < m and not fresh_l[i + 1] else safe_l[i]
        exit_[i] = nxt
        reach = math.sqrt(nxt * nxt + cap[i])
        if entry[i] > reach:
            entry[i] = reach
    for i in range(1, m):
        if fresh_l[i]:
            continue
        reach = math.sqrt(entry[i - 1] * entry[i - 1] + cap[i - 1])
        if entry[i] > reach:
            entry[i] = reach
        exit_[i - 1] = entry[i]
    v0 = np.asarray(entry)
    v1 = np.minimum(np.asarray(exit_), np.sqrt(v0 * v0 + 2.0 * acc * dist))

    # 5. Trapezoids.
    times[moving] += _trapezoid_time(v0, v1, np.maximum(cruise, np.maximum(v0, v1)), acc, dist)
    return times


def _limit_table(limit_sets: list[MachineLimits]) -> dict[str, np.ndarray]:
    """The limit sets as arrays, one row per set, so moves can index them."""
    return {
        "max_feedrate": np.array([s.max_feedrate for s in limit_sets], dtype=float),
        "max_acceleration": np.array([s.max_acceleration for s in limit_sets], dtype=float),
        "jerk": np.array([s.jerk for s in limit_sets], dtype=float),
        "junction_deviation": np.array(
            [np.nan if s.junction_deviation is None else s.junction_deviation for s in limit_sets]
        ),
        "print_acceleration": np.array([s.print_acceleration for s in limit_sets]),
        "retract_acceleration": np.array([s.retract_acceleration for s in limit_sets]),
        "travel_acceleration": np.array([s.travel_acceleration for s in limit_sets]),
        "min_feedrate": np.array([s.min_feedrate for s in limit_sets]),
        "min_travel_feedrate": np.array([s.min_travel_feedrate for s in limit_sets]),
    }


def _junction_speed(
    cruise: np.ndarray,
    axis_f: np.ndarray,
    safe: np.ndarray,
    jerk: np.ndarray,
    jd: np.ndarray,
    unit: np.ndarray,
    acc: np.ndarray,
) -> np.ndarray:
    """Largest speed through the junction between move i-1 and move i, for i = 1..m-1."""
    prev_c, curr_c = cruise[:-1], cruise[1:]
    vmax = np.minimum(prev_c, curr_c)
    # Marlin: when the previous move is faster, its exit velocity is scaled to the slower
    # cruise speed before the per-axis jerk comparison.
    smaller = np.where(prev_c > curr_c, curr_c / prev_c, 1.0)
    v_factor = np.ones_like(vmax)
    for a in range(4):
        v_exit = axis_f[:-1, a] * smaller * v_factor
        v_entry = axis_f[1:, a] * v_factor
        coasting_down = (v_entry > 0) | (v_exit < 0)
        coasting_up = (v_entry < 0) | (v_exit > 0)
        j = np.where(
            v_exit > v_entry,
            np.where(coasting_down, v_exit - v_entry, np.maximum(v_exit, -v_entry)),
            np.where(coasting_up, v_entry - v_exit, np.maximum(-v_exit, v_entry)),
        )
        limit = jerk[1:, a]
        # With junction deviation, X/Y/Z corners are judged by the angle instead (below).
        if a < 3:
            limit = np.where(np.isnan(jd[1:]), limit, np.inf)
        over = j > limit
        v_factor = np.where(over, v_factor * limit / np.where(over, j, 1.0), v_factor)
    classic = vmax * v_factor
    # Not coasting: Marlin then lets the move start from its own safe speed.
    threshold = classic * 0.99
    classic = np.where((safe[:-1] > threshold) & (safe[1:] > threshold), safe[1:], classic)

    has_jd = ~np.isnan(jd[1:])
    if not has_jd.any():
        return classic
    u0, u1 = unit[:-1, :3], unit[1:, :3]
    n0 = np.linalg.norm(u0, axis=1)
    n1 = np.linalg.norm(u1, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_theta = -(u0 * u1).sum(axis=1) / (n0 * n1)
        sin_half = np.sqrt(np.clip(0.5 * (1.0 - cos_theta), 0.0, 1.0))
        v_jd = np.sqrt(acc[1:] * jd[1:] * sin_half / np.maximum(1.0 - sin_half, 1e-12))
    v_jd = np.where(np.isfinite(v_jd) & (n0 > 0) & (n1 > 0), v_jd, classic)
    return np.where(has_jd, np.minimum(np.minimum(vmax * v_factor, v_jd), vmax), classic)


def _trapezoid_time(
    v0: np.ndarray, v1: np.ndarray, vc: np.ndarray, acc: np.ndarray, dist: np.ndarray
) -> np.ndarray:
    """Time to cover `dist` from `v0` to `v1`, cruising at `vc` at most, at acceleration `acc`."""
    d_acc = (vc * vc - v0 * v0) / (2.0 * acc)
    d_dec = (vc * vc - v1 * v1) / (2.0 * acc)
    cruise_d = dist - d_acc - d_dec
    trapezoid = (
        (vc - v0) / acc + (vc - v1) / acc + np.maximum(cruise_d, 0.0) / np.maximum(vc, 1e-12)
    )
    # Too short to reach cruise speed: accelerate to the peak and brake at once.
    peak = np.sqrt(np.maximum((2.0 * acc * dist + v0 * v0 + v1 * v1) / 2.0, 0.0))
    peak = np.maximum(peak, np.maximum(v0, v1))
    triangle = (peak - v0) / acc + (peak - v1) / acc
    return np.where(cruise_d >= 0, trapezoid, triangle)
