"""Solving in a crowd: the nearest robots first, then every other one the plan runs into.

A solve keeps clear of at most ``max_neighbours`` robots, the nearest of those that need it
(`neighbours.robots_to_avoid`): each one adds binaries. In a crowd that is not enough: 80 MPC
robots on the fleet scenario queue a dozen deep at a delivery point, and a lower robot's
optimal plan ran straight into a higher robot that was fourth or fifth nearest (left out, so
not kept clear of), which then stood in its way: 12 of the 13 contacts of that run (issue 16).
So a usable plan is checked against every robot it must keep clear of (`intrudes`) and, while
it runs into any that was left out, solved again with those added. The first solve is the
same as before; the loop ends, since each round adds at least one robot of a finite list.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from fleet_plugins.mpc.model import Solution, StepData, TripModel
from fleet_plugins.mpc.neighbours import brake_after
from fleet_plugins.mpc.separation import Obstacle, Separation, build_separation

__all__ = ["intrudes", "solve_clear", "touches"]


def intrudes(ob: Obstacle, p: np.ndarray) -> bool:
    """Whether plan `p` (steps 0..N) enters the hard part of `ob`'s box (its half-widths less
    the soft margin: contact of the two discs is inside it) at some instant after now, between
    the samples too.

    Over a step both the plan and the box's centre move in straight lines, so their difference
    does too; the box is taken at the larger of its two ends' half-widths. The difference
    segment enters the box when, along both axes at once, it is within the half-width.
    """
    p = np.asarray(p, dtype=float)
    n = min(len(p), len(ob.centres))
    d = p[:n] - ob.centres[:n]
    h = np.maximum(ob.half[: n - 1], ob.half[1:n]) - ob.margin  # (n-1, 2)
    d0, step = d[:-1], np.diff(d, axis=0)
    moving = np.abs(step) > 1e-12
    safe = np.where(moving, step, 1.0)
    # Where along each step, per axis, the difference is within (-h, h): the interval (a, b).
    a = np.where(moving, np.minimum((-h - d0) / safe, (h - d0) / safe), -np.inf)
    b = np.where(moving, np.maximum((-h - d0) / safe, (h - d0) / safe), np.inf)
    still_out = ~moving & (np.abs(d0) >= h)
    a, b = np.where(still_out, np.inf, a), np.where(still_out, -np.inf, b)
    lo = np.maximum(np.max(a, axis=1), 0.0)
    hi = np.minimum(np.min(b, axis=1), 1.0)
    return bool(np.any(lo < hi))


def touches(ob: Obstacle, p: np.ndarray, between: int = 8) -> bool:
    """Whether plan `p` (steps 0..N) comes closer than ``r_i + r_j`` (the two discs in
    contact) to where `ob`'s centre may be (its core box) after point 1, at the samples and at
    `between` points evenly spaced within each step (both move in straight lines there)."""
    p = np.asarray(p, dtype=float)
    n = min(len(p), len(ob.centres))
    if n < 3:
        return False
    core = ob.spread()[:n]
    contact = ob.half[:n, 0] - ob.margin - core[:, 0]  # r_i + r_j, as `separation._across`
    d = p[:n] - ob.centres[:n]
    f = np.linspace(0.0, 1.0, between + 1)[None, :, None]
    # From point 1 on (p[1] is fixed by the measured state, and out of contact).
    dd = d[1:-1, None, :] + f * (d[2:] - d[1:-1])[:, None, :]
    cc = np.maximum(core[1:-1], core[2:])[:, None, :]
    out = np.maximum(np.abs(dd) - cc, 0.0)
    gap = np.hypot(out[..., 0], out[..., 1])
    limit = np.minimum(contact[1:-1], contact[2:])[:, None]
    return bool(np.any(gap < limit - 1e-9))


def _into_contact_braking_avoids(
    softened: Solution, across: Sequence[Obstacle], model: TripModel, data: StepData
) -> bool:
    """Whether the `softened` plan comes into contact with one of the robots it had a side
    `across` where braking straight on from the measured state (``p[0]``, ``v[0]``, fixed in
    `data`) would not. Where both touch, the plan may still be the lesser contact (a robot
    passing one at rest at speed), and it is kept."""
    if softened.p is None:
        return False
    here, now = data.p_lo[0], data.v_lo[0]
    brake = brake_after(0.0, here, now, model.dt, model.a_max, len(data.p_lo) - 1)
    return any(touches(ob, softened.p) and not touches(ob, brake) for ob in across)


def solve_clear(
    model: TripModel,
    data: StepData,
    warm: np.ndarray | None,
    nearest: Sequence[Obstacle],
    first: int,
    p_lo: np.ndarray | None,
    p_hi: np.ndarray | None,
    spans: list[tuple[int, int]] | tuple[tuple[int, int], ...],
) -> tuple[Solution, Separation | None, tuple[Obstacle, ...]]:
    """Solve keeping clear of the first `first` of `nearest` (nearest first), then of every
    other one of `nearest` the plan `intrudes` on, again until the plan runs into none of
    them: the solution (its solver time summed over the rounds), its separation rows and the
    robots kept clear of. `p_lo`, `p_hi` bound the plan's points (needed when `nearest` is
    not empty); `spans` groups the steps (`separation.spans`)."""
    chosen = list(nearest[:first])
    left = list(nearest[first:])
    spent = 0.0
    while True:
        separation = None
        if chosen:
            assert p_lo is not None and p_hi is not None
            separation = build_separation(tuple(chosen), p_lo, p_hi, spans)
        solution = model.solve(data, warm, separation)
        if separation is not None and not solution.outcome.usable and separation.normals.any():
            # A side across a robot inside its square was too strict: soften that square
            # instead, so that the plan steers away rather than brakes (`build_separation`),
            # but not into contact where braking would keep out of it: then the fallback
            # brakes or follows the last plan, each checked on its own (fuzz s51-0000: 7 MPC
            # robots, a robot sliding round one at rest planned 0.80 m past it, radii 0.44,
            # where braking stopped 1.0 m off).
            assert p_lo is not None and p_hi is not None
            spent += solution.solver_s
            across = [ob for ob, n in zip(chosen, separation.normals, strict=True) if n.any()]
            soft_separation = build_separation(tuple(chosen), p_lo, p_hi, spans, across=False)
            softened = model.solve(data, warm, soft_separation)
            if not _into_contact_braking_avoids(softened, across, model, data):
                separation, solution = soft_separation, softened
            else:
                solution.solver_s += softened.solver_s
        solution.solver_s += spent
        spent = solution.solver_s
        if not solution.outcome.usable or solution.p is None:
            return solution, separation, tuple(chosen)
        hit = [intrudes(ob, solution.p) for ob in left]
        if not any(hit):
            return solution, separation, tuple(chosen)
        chosen += [ob for ob, h in zip(left, hit, strict=True) if h]
        left = [ob for ob, h in zip(left, hit, strict=True) if not h]
