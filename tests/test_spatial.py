"""Sensing's neighbours through a k-d tree (`fleet.engine.sensing.nearest_within`) are exactly
those of comparing every pair: the same robots in the same order, ties included."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from fleet.engine import World
from fleet.engine.sensing import MAX_NEIGHBOURS, nearest_within
from fleet.scenario import REPO_ROOT, load_scenario


def every_pair(xs, ys, ids, queries, radius, k):
    """The definition: every other point by (squared distance, id), those within `radius`."""
    out = []
    for i in queries:
        found = sorted(
            ((xs[j] - xs[i]) ** 2 + (ys[j] - ys[i]) ** 2, ids[j], j)
            for j in range(len(xs))
            if j != i
        )
        out.append([j for d2, _, j in found if d2 <= radius * radius][:k])
    return out


def points(kind: str, n: int, rng: np.random.Generator) -> tuple[list[float], list[float]]:
    if kind == "random":
        xy = rng.uniform(0.0, 80.0, size=(n, 2))
    elif kind == "lattice":
        # Many exactly equal distances: ties at the k-th neighbour and at the radius.
        side = math.ceil(math.sqrt(n))
        xy = np.array([(1.5 * (i % side), 1.5 * (i // side)) for i in range(n)], dtype=float)
    else:  # "crowded": a dense depot, some robots on the very same spot
        xy = rng.uniform(0.0, 3.0, size=(n, 2)).round(1)
    return xy[:, 0].tolist(), xy[:, 1].tolist()


@pytest.mark.parametrize("kind", ["random", "lattice", "crowded"])
@pytest.mark.parametrize("n", [5, 30, 400])
@pytest.mark.parametrize("radius", [1.5, 6.0, math.inf])
def test_the_tree_finds_what_every_pair_finds(kind, n, radius):
    rng = np.random.default_rng([n, int(min(radius, 99) * 10)])
    xs, ys = points(kind, n, rng)
    ids = [f"r{i:04d}" for i in rng.permutation(n)]  # ids in another order than the points
    queries = sorted(rng.choice(n, size=max(1, n // 2), replace=False).tolist())
    want = every_pair(xs, ys, ids, queries, radius, MAX_NEIGHBOURS)
    got = nearest_within(xs, ys, ids, queries, radius, MAX_NEIGHBOURS)
    assert got == want
    if kind == "lattice" and radius == 1.5 and n > 24:
        # The lattice puts 4 robots at exactly the radius: they count.
        assert max(len(g) for g in got) == 4


def test_a_tie_beyond_the_trees_spare_answers_is_kept():
    # 20 robots on a circle round the one asking: all at the same distance (to rounding).
    n = 40
    angles = np.linspace(0.0, 2 * math.pi, 20, endpoint=False)
    xs = [10.0] + (10.0 + 2.0 * np.cos(angles)).tolist()
    ys = [10.0] + (10.0 + 2.0 * np.sin(angles)).tolist()
    xs += [50.0 + i for i in range(n - len(xs))]
    ys += [50.0] * (n - len(ys))
    ids = [f"r{i:02d}" for i in range(n)][::-1]
    got = nearest_within(xs, ys, ids, [0], 6.0, MAX_NEIGHBOURS)
    assert got == every_pair(xs, ys, ids, [0], 6.0, MAX_NEIGHBOURS)
    assert len(got[0]) == MAX_NEIGHBOURS


def test_a_busy_fleets_observations_list_every_pairs_neighbours(monkeypatch):
    """A real 60-robot run (the tree's size) with sensing: at every bus round each observation's
    neighbours are the every-pair answer."""
    base = load_scenario(REPO_ROOT / "scenarios" / "default.toml")
    n = 60
    busy = replace(base.jobs, rate_per_h=30.0 * n, parts=())
    sc = replace(base.override(robots=n, duration=15.0), jobs=busy, parts={}, print_caps={})
    assert sc.sensing_radius_m > 0
    world = World(sc)
    sensing = world.sensing
    real = sensing._neighbours
    rounds = []

    def checked(robots, radius, t, priority):
        out = real(robots, radius, t, priority)
        everyone = list(world.robots.values())
        xs, ys = [o.x for o in everyone], [o.y for o in everyone]
        ids = [o.id for o in everyone]
        at = {o.id: i for i, o in enumerate(everyone)}
        want = every_pair(xs, ys, ids, [at[r.id] for r in robots], radius, MAX_NEIGHBOURS)
        for r, w in zip(robots, want, strict=True):
            assert [nb.robot for nb in out[r.id]] == [ids[j] for j in w]
        rounds.append(sum(len(v) for v in out.values()))
        return out

    monkeypatch.setattr(sensing, "_neighbours", checked)
    world.run()
    assert len(rounds) == 15.0 / sc.robots[0].period_s
    assert max(rounds) > 0  # robots saw each other


@pytest.mark.parametrize("n", [60, 300])
def test_the_safety_checkers_candidate_pairs_miss_no_contact(n):
    """Large fleets' contacts come from boxes per time window and a k-d tree: the same as
    comparing every pair of tracks, between samples too."""
    from fleet.engine.safety import _contacts, check_collisions

    rng = np.random.default_rng(n)
    steps = 12
    t = np.arange(steps) * 0.5
    # A crowded floor: robots drifting 0-1 m/s per axis, some starting on the same spot.
    start = rng.uniform(0.0, 14.0, size=(n, 2)).round(1)
    v = rng.uniform(-1.0, 1.0, size=(n, 2))
    xy = (start[:, None, :] + t[None, :, None] * v[:, None, :]).reshape(-1, 2)
    times, idx = np.tile(t, n), np.repeat(np.arange(n), steps)
    radii = rng.choice([0.3, 0.35, 0.4], size=n)
    names = [f"r{i:04d}" for i in range(n)]
    found = check_collisions(times, idx, xy, list(radii), names)
    tracks = [(t, xy[i * steps : (i + 1) * steps]) for i in range(n)]
    want = sorted(
        (when, names[i])
        for i in range(n)
        for j in range(i + 1, n)
        for when, _, _ in _contacts(*tracks[i], *tracks[j], radii[i] + radii[j] - 1e-9)
    )
    assert len(want) > n // 4  # crowded: the test could miss something
    assert sorted((f.t, f.robot) for f in found) == want


def test_kept_leg_times_are_the_computed_ones_and_cannot_be_spoilt():
    from fleet.floor import load_floor
    from fleet.paths.limits import SpeedLimits

    floor = load_floor(load_scenario(REPO_ROOT / "scenarios" / "default.toml").map)
    kept, fresh = SpeedLimits(floor, 1.0), SpeedLimits(floor, 1.0)
    rng = np.random.default_rng(3)
    P, Q = rng.uniform(0.0, 50.0, size=(18, 2)), rng.uniform(0.0, 50.0, size=(18, 2))
    for _ in range(2):  # the second time from the cache
        assert [kept.segment_time(p, q) for p, q in zip(P, Q, strict=True)] == [
            fresh._segment_time(p, q) for p, q in zip(P, Q, strict=True)
        ]
        t, ok = kept.travel_times(P, Q)
        t0, ok0 = fresh._travel_times(P, Q)
        assert t.tobytes() == t0.tobytes() and (ok == ok0).all()
        t[:] = -1.0  # a caller writing into its answer does not change the next one
        ok[:] = False
    assert len(kept._segment_times) == 18 and len(kept._batch_times) == 1
