"""The geometry of one trip: which regions the MPC may use, per horizon step, and with what Big-M.

A trip is one reference from the path layer (start -> goal). Its region set S is every region a
reference chord overlaps; the trip's MILP has binaries only for S, and each horizon step only
for the few regions of S around where the robot is expected to be (the corridor). Everything
here is plain numpy on the floor's H-representation; the Pyomo model is in `model.py`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from fleet.floor import BOUNDARY_BAND, Floor
from fleet.paths import Reference

__all__ = ["Face", "Trip", "reach_boxes", "MIDPOINT_MARGIN"]

#: How far (m) inside a face next to a slower region a step's midpoint must stay, so that a
#: step never runs *along* that face (the safety checker binds such a step by both sides).
MIDPOINT_MARGIN = 1e-5
#: Chords shorter than this (m) count as standing still.
_STILL = 1e-9


@dataclass(frozen=True, slots=True)
class Face:
    """One half-plane ``a . p <= b`` of a region, with its Big-M over the trip box."""

    region: int  # position in Trip.regions
    a: tuple[float, float]
    b: float
    big_m: float  # max of a . p - b over the trip box (<= 0: the face row is never needed)
    slower_side: bool  # a slower region lies across: the step's midpoint must stay inside


@dataclass(frozen=True)
class Trip:
    """Regions, faces and corridor data of one reference.

    Attributes
    ----------
    reference:
        The path layer's time-parameterised reference.
    regions:
        Floor region indices of the trip's set S, sorted.
    v_max:
        ``(len(S), 2)`` per-axis limits of those regions.
    faces:
        Every face of every region in S whose Big-M is positive.
    box:
        ``(xlo, ylo, xhi, yhi)``: the bounding box of S; every p[k], k >= 1, lies in it.
    chord_sets:
        For each reference sample i (0..K), the positions in `regions` of the regions chord
        i -> i+1 overlaps (for i = K: the regions holding the goal).
    region_boxes:
        ``(len(S), 4)`` bounding boxes, for the reachability filter.
    hulls:
        ``(A, b)`` of each region of S (``A p <= b`` inside), to tell which hold a point.
    """

    reference: Reference
    regions: tuple[int, ...]
    v_max: np.ndarray
    faces: tuple[Face, ...]
    box: tuple[float, float, float, float]
    chord_sets: tuple[frozenset[int], ...]
    region_boxes: np.ndarray
    hulls: tuple[tuple[np.ndarray, np.ndarray], ...]

    @classmethod
    def build(cls, floor: Floor, reference: Reference) -> Trip:
        pos = reference.positions
        chords: list[set[int]] = []
        for i in range(len(pos)):
            q = pos[min(i + 1, len(pos) - 1)]
            chords.append(_regions_touched(floor, pos[i], q))
        region_ids = sorted(set().union(*chords))
        where = {r: n for n, r in enumerate(region_ids)}
        polys = [floor.regions[r].polygon for r in region_ids]
        boxes = np.array([p.bounds for p in polys], dtype=float)
        box = (
            float(boxes[:, 0].min()),
            float(boxes[:, 1].min()),
            float(boxes[:, 2].max()),
            float(boxes[:, 3].max()),
        )
        faces = []
        for n, r in enumerate(region_ids):
            region = floor.regions[r]
            slower = _slower_faces(floor, r)
            for f in range(len(region.b)):
                a = (float(region.A[f, 0]), float(region.A[f, 1]))
                b = float(region.b[f])
                big_m = _big_m(a, b, box)
                # A face the trip box never crosses needs no row, unless a slower region lies
                # across it: a step along it must still be kept off it (the midpoint cut).
                if big_m > 1e-9 or f in slower:
                    faces.append(Face(n, a, b, big_m, f in slower))
        return cls(
            reference=reference,
            regions=tuple(region_ids),
            v_max=np.array([floor.regions[r].v_max for r in region_ids], dtype=float),
            faces=tuple(faces),
            box=box,
            chord_sets=tuple(frozenset(where[r] for r in c) for c in chords),
            region_boxes=boxes,
            hulls=tuple((floor.regions[r].A, floor.regions[r].b) for r in region_ids),
        )

    def progress(self, points: np.ndarray, lo: int, width: int) -> np.ndarray:
        """For each point, the reference sample nearest to it among ``lo .. lo + width``.

        Ties go to the later sample (the reference starts and ends with repeated samples at
        rest, and the robot has progressed past all of them).
        """
        pos = self.reference.positions
        hi = min(len(pos), lo + width + 1)
        lo = max(0, min(lo, hi - 1))
        d = np.hypot(
            pos[None, lo:hi, 0] - points[:, None, 0], pos[None, lo:hi, 1] - points[:, None, 1]
        )
        best = d.min(axis=1, keepdims=True)
        # The last index within a rounding error of the minimum.
        last = (hi - lo - 1) - np.argmax((d <= best + 1e-9)[:, ::-1], axis=1)
        return lo + last

    def progress_in_sight(self, point: np.ndarray, lo: int, width: int) -> tuple[int, bool]:
        """`progress` of one point, counting only samples whose chord runs through a region
        that holds the point (convex: a chord the robot can see); and whether there was one.

        The nearest sample as the crow flies can lie across a thin wall, where the reference
        comes back on the other side: the robot then tracks that stretch on the wrong side of
        the wall and comes to rest against it for good (fuzz s73-0631). With no such sample
        in the window (the robot went out of sight of the chords ahead, round a neighbour or
        backing off, or stands off the trip's regions), the progress stays at `lo`.
        """
        pos = self.reference.positions
        hi = min(len(pos), lo + width + 1)
        lo = max(0, min(lo, hi - 1))
        here = self.holding(point)
        seen = np.array([i for i in range(lo, hi) if self.chord_sets[i] & here], dtype=int)
        if not len(seen):
            return lo, False
        d = np.hypot(pos[seen, 0] - point[0], pos[seen, 1] - point[1])
        return int(seen[d <= d.min() + 1e-9][-1]), True  # ties: the later, as `progress`

    def holding(self, point: np.ndarray, tol: float = BOUNDARY_BAND) -> frozenset[int]:
        """Positions in `regions` of the regions that hold `point` (to `tol` m)."""
        return frozenset(
            n for n, (A, b) in enumerate(self.hulls) if float(np.max(A @ point - b)) <= tol
        )

    def chord_meeting(self, regions: frozenset[int], near: int) -> int | None:
        """The chord nearest sample `near` (the earlier on a tie) that overlaps one of
        `regions` (positions in `regions`); None if none does."""
        hits = [i for i, c in enumerate(self.chord_sets) if c & regions]
        if not hits:
            return None
        return min(hits, key=lambda i: (abs(i - near), i))

    def corridor(self, first: int, last: int) -> frozenset[int]:
        """Regions (positions in `regions`) of chords ``first .. last``, clamped to the trip."""
        top = len(self.chord_sets) - 1
        out: set[int] = set()
        for i in range(max(0, first), min(top, last) + 1):
            out |= self.chord_sets[i]
        if last > top:
            out |= self.chord_sets[top]
        return frozenset(out)


def reach_boxes(
    p0: np.ndarray, v0: np.ndarray, v_bound: np.ndarray, dt: float, a_max: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis bounds of p[0..N] and v[0..N] reachable from (p0, v0).

    `v_bound` is ``(N+1, 2)``: the speed bound of each step's velocity (v[0] is v0 itself).
    Returns ``(p_lo, p_hi)``, each ``(N+1, 2)``.
    """
    n = len(v_bound)
    k = np.arange(n)[:, None]
    v_lo = np.maximum(-v_bound, v0[None, :] - k * a_max * dt)
    v_hi = np.minimum(v_bound, v0[None, :] + k * a_max * dt)
    v_lo[0] = v_hi[0] = v0
    # Rounding may cross the bounds over when a bound equals the braking limit.
    v_hi = np.maximum(v_hi, v_lo)
    p_lo = np.empty((n, 2))
    p_hi = np.empty((n, 2))
    p_lo[0] = p_hi[0] = p0
    p_lo[1:] = p0 + dt * np.cumsum(v_lo[:-1], axis=0)
    p_hi[1:] = p0 + dt * np.cumsum(v_hi[:-1], axis=0)
    return p_lo, p_hi


def _regions_touched(floor: Floor, p: np.ndarray, q: np.ndarray) -> set[int]:
    """Regions a chord p -> q overlaps with positive length (or that hold p when p == q)."""
    if float(np.hypot(*(q - p))) <= _STILL:
        point = shapely.Point(float(p[0]), float(p[1]))
        hits = floor.tree.query(point.buffer(1e-7), predicate="intersects")
        found = {int(i) for i in hits}
        located = floor.locate(float(p[0]), float(p[1]))
        if located is not None:
            found.add(located)
        return found
    line = shapely.LineString([p, q])
    hits = floor.tree.query(line, predicate="intersects")
    found = set()
    for i in hits:
        piece = shapely.intersection(line, floor.regions[int(i)].polygon)
        if piece.length > 1e-9:
            found.add(int(i))
    if not found:  # a chord a rounding error outside: take the regions around its midpoint
        m = (p + q) / 2
        located = floor.locate(float(m[0]), float(m[1]))
        if located is not None:
            found.add(located)
    return found


def _slower_faces(floor: Floor, r: int) -> set[int]:
    """Faces of region r that border a region slower on some axis."""
    region = floor.regions[r]
    out: set[int] = set()
    for nb in floor.graph.neighbors(r):
        other = floor.regions[nb]
        if not (other.v_max[0] < region.v_max[0] or other.v_max[1] < region.v_max[1]):
            continue
        portal = floor.graph.edges[r, nb]["portal"]
        pts = np.asarray(portal.coords)
        residual = np.abs(pts @ region.A.T - region.b).max(axis=0)
        out.add(int(np.argmin(residual)))
    return out


def _big_m(a: tuple[float, float], b: float, box: tuple[float, float, float, float]) -> float:
    x0, y0, x1, y1 = box
    return max(a[0] * x0, a[0] * x1) + max(a[1] * y0, a[1] * y1) - b
