"""This tick's horizon: what each step of a solve may do, and what it tracks.

For steps 0..N of one solve (`step_data`): the speed bounds (robot limit and print caps, never
below what braking reaches), the reachable boxes, the corridor of regions each step may use and
the reference window (`reference_window`: the path layer's timed samples, slowed where a cap
is slower, following the robot's progress when it falls behind). `region_bounds` narrows the
reachable boxes to the regions the steps may use, for the separation rows.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from shapely.geometry import Point
from shapely.ops import nearest_points

from fleet.floor import BOUNDARY_BAND, Floor
from fleet.paths import Reference
from fleet.plugins import Observation, RobotSpec
from fleet.printing import CapSchedule
from fleet_plugins.mpc.model import Solution, StepData
from fleet_plugins.mpc.trip import Trip, reach_boxes

__all__ = [
    "PROGRESS_WINDOW",
    "step_data",
    "rejoin",
    "reference_window",
    "region_bounds",
    "into_regions",
]

#: How far ahead (samples) the progress search along the reference looks.
PROGRESS_WINDOW = 8


def into_regions(obs: Observation, floor: Floor, trip: Trip) -> Observation:
    """`obs`, or, its position outside every region of the trip by at most `BOUNDARY_BAND`
    (the floor checker's band), `obs` at the nearest point of the nearest of them.

    The first plan point is fixed by the measured state, so a robot a hair outside its regions
    makes every solve infeasible, and every new trip from there too (fuzz case s42-0010: a
    robot pressed against a region's edge drifted across it at 8e-10 m/s, a speed under
    `fallback.REST_SPEED` that nothing cancelled, and stood 150 s, 438 infeasible solves).
    """
    p = np.array([obs.x, obs.y])
    out = [float(np.max(floor.regions[r].A @ p - floor.regions[r].b)) for r in trip.regions]
    n = int(np.argmin(out))
    if out[n] <= 0.0 or out[n] > BOUNDARY_BAND:
        return obs
    q = nearest_points(floor.regions[trip.regions[n]].polygon, Point(obs.x, obs.y))[0]
    return dataclasses.replace(obs, x=float(q.x), y=float(q.y))


def step_data(
    obs: Observation,
    spec: RobotSpec,
    trip: Trip,
    *,
    horizon: int,
    corridor: int,
    progress: int,
    last: Solution | None,
    wide: bool = False,
    corridor_steps: int | None = None,
) -> tuple[StepData, int]:
    """Bounds, corridor and reference window for this tick, and the robot's progress.

    `progress` is the robot's sample along the reference at the previous tick; `last` the
    previous plan when the robot is on it (in this trip), else None. `wide` opens every step's
    corridor back to the robot's own progress, for when the plan cannot keep pace with the
    reference window (the retry after an infeasible solve). Steps after `corridor_steps`
    (None: none) use only the chords between the reference's and the expected progress, unless
    `wide`.
    """
    N, dt, a = horizon, spec.period, spec.a_max
    ref = trip.reference
    last_index = ref.steps
    p0 = np.array([obs.x, obs.y])
    v0 = np.array([obs.vx, obs.vy])

    # Speed bounds per step: robot limit and print caps, never below what braking at full
    # deceleration reaches (a cap that starts too soon is then missed by the least possible,
    # instead of making the problem infeasible).
    caps = CapSchedule(obs.speed_caps).step_caps(obs.t, dt, N + 1)
    bound = np.minimum(spec.v_max, caps)[:, None].repeat(2, axis=1)
    bound[N] = 0.0  # end at rest
    braking = np.abs(v0)[None, :] - np.arange(N + 1)[:, None] * a * dt
    bound = np.maximum(bound, braking)
    p_lo, p_hi = reach_boxes(p0, v0, bound, dt, a)
    xlo, ylo, xhi, yhi = trip.box
    p_lo[1:] = np.maximum(p_lo[1:], [xlo, ylo])
    p_hi[1:] = np.minimum(p_hi[1:], [xhi, yhi])
    p_hi[1:] = np.maximum(p_hi[1:], p_lo[1:])  # empty box: leave it to HiGHS to say so
    v_lo, v_hi = -bound.copy(), bound.copy()
    v_lo[0] = v_hi[0] = v0

    # Where along the reference: on time, the timed sample; behind, just past the progress.
    # Out of sight of the chords ahead, the window waits at the progress until the robot is
    # back: run ahead, it pulls the robot towards where the route goes as the crow flies,
    # maybe across a wall (fuzz s73-0631: at rest for good right across one from its goal).
    progress, in_sight = trip.progress_in_sight(p0, progress, PROGRESS_WINDOW)
    timed = ref.index(obs.t)
    base = min(max(timed, progress), progress + 1) if in_sight else progress
    pace = np.minimum(spec.v_max, caps) if in_sight else np.zeros_like(caps)
    p_ref, v_ref, at = reference_window(ref, base, pace, dt)
    # The chord each step's reference starts on, and the last chord it reaches: step k
    # runs along the reference from at[k] to at[k+1].
    chord = np.minimum(np.floor(at).astype(int), last_index)
    chord_end = np.maximum(np.ceil(at[1:]).astype(int) - 1, chord[:-1])

    # Corridor: chords around both where the reference is and where the last plan expected
    # the robot to be, plus the region the last plan used (so the shifted plan stays open).
    expected = chord
    if last is not None:
        assert last.p is not None
        shifted = np.vstack([last.p[1:], last.p[-1:]])
        expected = trip.progress(shifted, progress, N + PROGRESS_WINDOW)
    z_ub = np.zeros((N - 1, len(trip.regions)))
    # Far steps' region choices are the costliest to search and are solved again before the
    # robot gets there; near ones need room to go round a neighbour.
    near = N if wide or corridor_steps is None else corridor_steps
    join = None
    for k in range(1, N):
        w = corridor if k <= near else 0
        lo = min(expected[k], chord[k]) - w
        if wide:
            lo = min(lo, progress - w)
        hi = max(expected[k + 1], chord_end[k]) + w
        if k == 1:
            join = rejoin(trip, p0 + dt * v0, lo, hi)
        if join is not None:
            lo, hi = min(lo, join), max(hi, join)
        allowed = set(trip.corridor(lo, hi))
        if last is not None:
            assert last.regions is not None
            allowed.add(int(last.regions[min(k, N - 2)]))
        for j in allowed:
            z_ub[k - 1, j] = 1.0
        # Keep only regions whose box meets where the step can be.
        lo_box = np.minimum(p_lo[k], p_lo[k + 1])
        hi_box = np.maximum(p_hi[k], p_hi[k + 1])
        rb = trip.region_boxes
        outside = (
            (rb[:, 0] > hi_box[0] + 1e-9)
            | (rb[:, 2] < lo_box[0] - 1e-9)
            | (rb[:, 1] > hi_box[1] + 1e-9)
            | (rb[:, 3] < lo_box[1] - 1e-9)
        )
        z_ub[k - 1, outside] = 0.0
    return StepData(p_lo, p_hi, v_lo, v_hi, z_ub, p_ref, v_ref), progress


def rejoin(trip: Trip, p1: np.ndarray, lo: int, hi: int) -> int | None:
    """The chord to open the corridor to when the robot's first planned point `p1` lies in
    none of the regions of chords ``lo .. hi`` (the first step's corridor); else None.

    Progress along the reference was the nearest sample, as the crow flies. A robot that went
    round a neighbour on the other side of a corner was nearest to a sample past the corner
    while it stood in a region the reference left before it: the corridor's regions then did
    not meet its own (only the previous plan's region held it), every solve was optimal at rest
    and the robot stayed there for good (fuzz s21-0087: 155 s with its job, a neighbour in
    sight so `fallback.stays_put` never fired). Progress now counts only chords in sight
    (`Trip.progress_in_sight`), but a robot out of sight of them all, its progress held, is
    as far from the corridor. Opening every step's corridor to the chord nearest the progress
    that overlaps the robot's region joins the two: consecutive chords meet at a sample, so
    chords ``lo .. hi`` with it are one chain of regions that meet.
    """
    here = trip.holding(p1)
    if not here or here & trip.corridor(lo, hi):
        return None
    return trip.chord_meeting(here, min(max(lo, 0), hi))


def reference_window(
    ref: Reference, base: int, speed: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reference for horizon steps 0..N, starting at sample `base`, slowed to `speed`.

    Where the reference is faster (per axis) than step k's allowed speed (a print cap), it is
    retimed: it advances only the fraction ``speed / |v_ref|`` of a sample per step, along the
    same chords, with its velocity scaled alike. Without caps this is samples ``base + k``.
    Returns positions and velocities ``(N+1, 2)`` and the fractional sample index of each step.
    """
    last = ref.steps
    pos, vel = ref.positions, ref.velocities
    n = len(speed)
    p_ref = np.empty((n, 2))
    v_ref = np.empty((n, 2))
    at = np.empty(n)
    s = float(base)
    for k in range(n):
        s = min(s, float(last))
        i = int(s)
        frac = s - i
        fastest = max(abs(vel[i, 0]), abs(vel[i, 1]))
        scale = 1.0 if fastest <= speed[k] or fastest < 1e-12 else speed[k] / fastest
        # Along chord i: p[i] + frac * dt * v[i] (the chord is the step p[i] -> p[i+1]).
        p_ref[k] = pos[i] + frac * dt * vel[i]
        v_ref[k] = vel[i] * scale
        at[k] = s
        s += scale
    return p_ref, v_ref, at


def region_bounds(trip: Trip, horizon: int, data: StepData) -> tuple[np.ndarray, np.ndarray]:
    """Where each p[k] can be: the reachable box within the boxes of the regions its
    steps may use (p[k] lies in the region of step k-1 and of step k)."""
    boxes = trip.region_boxes
    N = horizon
    allowed = data.z_ub > 0.5  # (N-1, |S|), steps 1..N-1
    inf = np.inf
    lo_s = np.where(allowed[:, :, None], boxes[None, :, :2], inf).min(axis=1)  # (N-1, 2)
    hi_s = np.where(allowed[:, :, None], boxes[None, :, 2:], -inf).max(axis=1)
    none = ~allowed.any(axis=1)  # no region open (the solve is infeasible): no narrowing
    lo_s[none], hi_s[none] = -inf, inf
    lo = np.full((N + 1, 2), -inf)
    hi = np.full((N + 1, 2), inf)
    # Point k is an end of steps k-1 and k (for k - 1 >= 1 and k <= N - 1).
    lo[1:N] = np.maximum(lo[1:N], lo_s)
    hi[1:N] = np.minimum(hi[1:N], hi_s)
    lo[2 : N + 1] = np.maximum(lo[2 : N + 1], lo_s)
    hi[2 : N + 1] = np.minimum(hi[2 : N + 1], hi_s)
    p_lo = np.maximum(data.p_lo, lo)
    p_hi = np.minimum(data.p_hi, hi)
    p_hi = np.maximum(p_hi, p_lo)  # an empty box: left for HiGHS to find infeasible
    return p_lo, p_hi
