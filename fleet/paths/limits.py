"""Zone speed limits along segments: the limit a step must obey, and the time a leg takes.

The floor's convex regions are held in H-representation (``A x <= b``) and segments are clipped
against them (Cyrus-Beck), vectorised over many segments at once. A segment's limit is the
component-wise minimum of the per-axis limits of every region it overlaps with positive length,
and of the robot's own limit; a segment that leaves the free space has none. One too short to
overlap any region by `OVERLAP_TOL` is judged as a point is, by where it starts. A segment that
runs along a region's boundary (within `fleet.floor.BOUNDARY_BAND` of it for more than
`ALONG_M`) is bound by that region too over that stretch, even from just outside it: the safety
checker binds a step that enters no region deeper than the band by the regions on both sides.
"""

from __future__ import annotations

__all__ = [
    "GAP_TOL",
    "ALONG_M",
    "ON_LINE_TOL",
    "OVERLAP_TOL",
    "SpeedLimits",
    "speed_along",
    "speeds_along",
    "speeds_along_rows",
]

import math

import numpy as np

from fleet.floor.compiled import BOUNDARY_BAND, Floor
from fleet.floor.compiled import TOLERANCE as FLOOR_TOLERANCE

#: A segment overlaps a region when they share more than this length (m); less is a point touch.
OVERLAP_TOL = 1e-9
#: Longest stretch (m) of a segment outside every region that is forgiven as rounding.
GAP_TOL = 1e-6
#: Distance (m) within which a point counts as lying on a region's boundary line.
ON_LINE_TOL = 1e-9
#: Length (m) a segment must run within `BOUNDARY_BAND` of a region, beyond what it overlaps
#: it, to be bound by it there: a leg running along the boundary, not one crossing it or
#: touching a corner (those come within the band for ``2 * BOUNDARY_BAND / sin(angle)``).
ALONG_M = 1e-3

_PARALLEL = 1e-12  # |cos| below which a segment runs parallel to a boundary line
#: Leg times `SpeedLimits.segment_time` keeps (about 100 bytes each); when full it forgets
#: them all and starts over.
CACHE_ENTRIES = 1 << 16
#: Batches `SpeedLimits.travel_times` keeps (about 1 kB each for the 18 legs of a waypoint's
#: slide); likewise.
BATCH_CACHE_ENTRIES = 1 << 13


class SpeedLimits:
    """The speed limits of one floor's zones for one robot, along any segment.

    Parameters
    ----------
    floor:
        The compiled floor.
    v_max:
        The robot's own per-axis speed limit (m/s), applied on top of the zone limits.
    """

    def __init__(self, floor: Floor, v_max: float) -> None:
        self.v_max = v_max
        regions = floor.regions
        self._A = np.vstack([r.A for r in regions])
        self._b = np.concatenate([r.b for r in regions])
        self._counts = np.array([len(r.b) for r in regions], dtype=np.intp)
        first = np.concatenate([[0], np.cumsum(self._counts)[:-1]]).astype(np.intp)
        self._rows = [np.arange(f, f + c) for f, c in zip(first, self._counts, strict=True)]
        self._bbox = np.array([r.polygon.bounds for r in regions], dtype=float)
        #: Per-axis limit (vx, vy) of each region, capped by the robot's own.
        self.per_region = np.minimum(np.array([r.v_max for r in regions], dtype=float), v_max)
        # Path searches ask the same legs again and again (string pulling, sliding waypoints,
        # trips from the same stations): answers kept by the exact bytes of the query.
        self._segment_times: dict[bytes, float | None] = {}
        self._batch_times: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

    def clip(
        self, P: np.ndarray, Q: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Clip segments ``P[i] -> Q[i]`` against the regions near them (Cyrus-Beck).

        Returns ``L`` (n,), ``u`` (n, 2) unit directions, ``lo`` and ``hi`` (n, m): the overlap
        with region ``sel[j]`` is ``[lo[:, j], hi[:, j]]`` in metres along the segment (empty if
        lo > hi), ``contains`` (n, m): whether that region holds the start point, and ``sel``
        (m,): the regions whose bounding box meets the segments' (the others cannot overlap).
        """
        L, u, lo, hi, contains, sel, _, _ = self._clip(P, Q, 0.0)
        return L, u, lo, hi, contains, sel

    def _clip(self, P: np.ndarray, Q: np.ndarray, band: float) -> tuple[np.ndarray, ...]:
        """`clip`, and with `band` > 0 also ``lo, hi`` of the regions grown by `band` metres
        (the rows of ``A`` are unit normals), in the same pass; ``sel`` then takes in the
        regions within `band` too."""
        d = Q - P
        L = np.hypot(d[:, 0], d[:, 1])
        u = d / np.where(L > 0, L, 1.0)[:, None]
        pad = FLOOR_TOLERANCE + band
        lo_xy = np.minimum(P.min(axis=0), Q.min(axis=0)) - pad
        hi_xy = np.maximum(P.max(axis=0), Q.max(axis=0)) + pad
        box = self._bbox
        sel = np.flatnonzero(
            (box[:, 0] <= hi_xy[0])
            & (box[:, 2] >= lo_xy[0])
            & (box[:, 1] <= hi_xy[1])
            & (box[:, 3] >= lo_xy[1])
        )
        n = len(L)
        if len(sel) == 0:
            empty = np.zeros((n, 0))
            return L, u, empty, empty, empty.astype(bool), sel, empty, empty
        rows = np.concatenate([self._rows[i] for i in sel])
        offsets = np.concatenate([[0], np.cumsum(self._counts[sel])[:-1]]).astype(np.intp)
        A, b = self._A[rows], self._b[rows]
        num = b[None, :] - P @ A.T
        den = u @ A.T
        par = np.abs(den) <= _PARALLEL
        ahead = den > _PARALLEL
        behind = den < -_PARALLEL

        def overlaps(num: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            with np.errstate(divide="ignore", invalid="ignore"):
                bound = num / den
            upper = np.where(ahead, bound, np.inf)
            lower = np.where(behind, bound, -np.inf)
            # Running along (or outside) a boundary line: the whole segment is in or out of it.
            upper = np.where(par & (num < -ON_LINE_TOL), -np.inf, upper)
            hi = np.minimum(np.minimum.reduceat(upper, offsets, axis=1), L[:, None])
            lo = np.maximum(np.maximum.reduceat(lower, offsets, axis=1), 0.0)
            return lo, hi

        lo, hi = overlaps(num)
        contains = np.logical_and.reduceat(num >= -FLOOR_TOLERANCE, offsets, axis=1)
        # Only a segment nearly parallel to a boundary line (it is in the band for at most
        # 2 * band / |den| metres) that comes within the band of it, outside, can run along it
        # for `ALONG_M`: most calls have none and skip the second pass.
        lo_b, hi_b = lo, hi
        if band > 0:
            num_q = num - L[:, None] * den
            if np.any(
                (np.abs(den) * ALONG_M < 2.0 * band)
                & (np.maximum(num, num_q) >= -band)
                & (np.minimum(num, num_q) <= 0.0)
            ):
                lo_b, hi_b = overlaps(num + band)
        return L, u, lo, hi, contains, sel, lo_b, hi_b

    def of_segments(self, P: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised `PathPlanner.speed_limit`: limits (n, 2) and whether each segment is free."""
        L, _, lo, hi, contains, sel, lo_b, hi_b = self._clip(P, Q, BOUNDARY_BAND)
        point = _point_like(L, lo, hi)
        free = self._covered(L, lo, hi, contains, point)
        lo, hi = _binding(lo, hi, lo_b, hi_b)
        over = (hi - lo) > OVERLAP_TOL
        use = np.where(point[:, None], contains, over)
        lim = np.where(use[:, :, None], self.per_region[sel][None, :, :], np.inf).min(
            axis=1, initial=np.inf
        )
        lim = np.minimum(lim, self.v_max)
        return lim, free

    def _covered(self, L, lo, hi, contains, point=None) -> np.ndarray:
        """Whether each clipped segment stays in the free space (no gap over `GAP_TOL`);
        `point` is `_point_like` of the same segments when the caller has it."""
        if lo.shape[1] == 0:
            return np.zeros(len(L), dtype=bool)
        if point is None:
            point = _point_like(L, lo, hi)
        over = (hi - lo) > OVERLAP_TOL
        # Covered when the overlaps, sorted by start, leave no gap longer than GAP_TOL.
        lo_m = np.where(over, lo, np.inf)
        hi_m = np.where(over, hi, -np.inf)
        order = np.argsort(lo_m, axis=1)
        lo_s = np.take_along_axis(lo_m, order, axis=1)
        reach = np.maximum.accumulate(np.take_along_axis(hi_m, order, axis=1), axis=1)
        before = np.concatenate([np.zeros((len(L), 1)), reach[:, :-1]], axis=1)
        gaps = np.where(np.isfinite(lo_s), lo_s - before, 0.0)
        ok = np.all(gaps <= GAP_TOL, axis=1) & (reach[:, -1] >= L - GAP_TOL)
        return np.where(point, contains.any(axis=1), ok)

    def stretches(
        self, p: np.ndarray, q: np.ndarray
    ) -> list[tuple[float, float, np.ndarray]] | None:
        """Split ``p -> q`` where its speed limit changes: ``[(from_m, to_m, (vx, vy)), ...]``.

        Each stretch's limit is the minimum over the regions it overlaps with positive length
        or runs along (see the module docstring), so any sub-segment of a stretch obeys it.
        None if the segment leaves the free space.
        """
        L, _, lo, hi, contains, sel, lo_b, hi_b = self._clip(p[None, :], q[None, :], BOUNDARY_BAND)
        if _point_like(L, lo, hi)[0]:
            return [] if contains.any() else None
        lo_b, hi_b = _binding(lo, hi, lo_b, hi_b)
        L, lo, hi, lo_b, hi_b = float(L[0]), lo[0], hi[0], lo_b[0], hi_b[0]
        over = np.flatnonzero((hi - lo) > OVERLAP_TOL)
        near = np.flatnonzero((hi_b - lo_b) > OVERLAP_TOL)
        cuts = np.sort(np.concatenate([[0.0, L], lo[over], hi[over], lo_b[near], hi_b[near]]))
        kept = [0.0]
        for c in cuts[1:]:
            if c - kept[-1] > OVERLAP_TOL:
                kept.append(float(c))
        kept[-1] = L
        out: list[tuple[float, float, np.ndarray]] = []
        for a, b in zip(kept[:-1], kept[1:], strict=True):
            cover = over[(lo[over] <= a + OVERLAP_TOL) & (hi[over] >= b - OVERLAP_TOL)]
            if len(cover) == 0:
                if b - a > GAP_TOL:
                    return None
                # A rounding gap between regions joins the stretch before it (or after it).
                if out:
                    out[-1] = (out[-1][0], b, out[-1][2])
                continue
            bound = near[(lo_b[near] < b - OVERLAP_TOL) & (hi_b[near] > a + OVERLAP_TOL)]
            lim = np.minimum(self.per_region[sel[bound]].min(axis=0), self.v_max)
            if out and np.array_equal(out[-1][2], lim):
                out[-1] = (out[-1][0], b, lim)
            else:
                out.append((a if out else 0.0, b, lim))
        return out or None

    def segment_time(self, p: np.ndarray, q: np.ndarray) -> float | None:
        """Time (s) to drive ``p -> q`` with every stretch at its limit; None if not free."""
        p, q = np.asarray(p, dtype=float), np.asarray(q, dtype=float)
        key = p.tobytes() + q.tobytes()
        cache = self._segment_times
        if key in cache:
            return cache[key]
        if len(cache) >= CACHE_ENTRIES:
            cache.clear()
        t = cache[key] = self._segment_time(p, q)
        return t

    def _segment_time(self, p: np.ndarray, q: np.ndarray) -> float | None:
        parts = self.stretches(p, q)
        if parts is None:
            return None
        d = q - p
        L = math.hypot(d[0], d[1])
        if L == 0.0:
            return 0.0
        u = d / L
        return sum((b - a) / speed_along(lim, u) for a, b, lim in parts)

    def travel_times(self, P: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised travel times of segments ``P[i] -> Q[i]`` and whether each is free.

        Each region's overlap is driven at that region's limit; a stretch along a shared
        boundary counts once per region, so the time is exact or an overestimate.
        """
        P, Q = np.asarray(P, dtype=float), np.asarray(Q, dtype=float)
        # The whole batch is the key: which regions are clipped depends on all its segments.
        key = P.shape[0].to_bytes(8, "little") + P.tobytes() + Q.tobytes()
        cache = self._batch_times
        hit = cache.get(key)
        if hit is None:
            if len(cache) >= BATCH_CACHE_ENTRIES:
                cache.clear()
            hit = cache[key] = self._travel_times(P, Q)
        return hit[0].copy(), hit[1].copy()

    def _travel_times(self, P: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        L, u, lo, hi, contains, sel = self.clip(P, Q)
        over = np.maximum(hi - lo, 0.0)
        over = np.where(over > OVERLAP_TOL, over, 0.0)
        with np.errstate(divide="ignore"):
            speed = np.where(
                np.abs(u)[:, None, :] > 0,
                self.per_region[sel][None] / np.abs(u)[:, None, :],
                np.inf,
            )
        t = (over / speed.min(axis=2)).sum(axis=1)
        return t, self._covered(L, lo, hi, contains)


def _binding(
    lo: np.ndarray, hi: np.ndarray, lo_b: np.ndarray, hi_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Where each region binds each segment: its overlap ``[lo, hi]``, or, where the segment
    runs along its boundary (within the band for `ALONG_M` more than it overlaps it), its
    overlap with the region grown by the band ``[lo_b, hi_b]``."""
    along = (hi_b - lo_b) - np.maximum(hi - lo, 0.0) > ALONG_M
    return np.where(along, lo_b, lo), np.where(along, hi_b, hi)


def speed_along(lim: np.ndarray, u: np.ndarray) -> float:
    """Highest speed along unit direction `u` inside the per-axis box `lim`."""
    best = math.inf
    for axis in (0, 1):
        c = abs(float(u[axis]))
        if c > 0:
            best = min(best, float(lim[axis]) / c)
    return best


def speeds_along(lim: np.ndarray, u: np.ndarray) -> np.ndarray:
    """`speed_along` for one limit and many directions (rows of `u`)."""
    return speeds_along_rows(np.broadcast_to(lim, u.shape), u)


def speeds_along_rows(lim: np.ndarray, u: np.ndarray) -> np.ndarray:
    """`speed_along` for many limits and directions, row by row."""
    with np.errstate(divide="ignore"):
        r = np.where(np.abs(u) > 0, lim / np.abs(u), np.inf)
    return r.min(axis=1)


def _point_like(L: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Segments judged by where they start, not by what they overlap: those no longer than
    `OVERLAP_TOL`, and those no longer than `GAP_TOL` that overlap no region by more than
    `OVERLAP_TOL` (a step of a few nanometres across a boundary between regions)."""
    over = ((hi - lo) > OVERLAP_TOL).any(axis=1) if lo.shape[1] else np.zeros(len(L), bool)
    return (L <= OVERLAP_TOL) | ((L <= GAP_TOL) & ~over)
