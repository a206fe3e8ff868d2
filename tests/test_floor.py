"""Compiling floors: configuration space, speed cells, convex decomposition, shipped maps."""

from __future__ import annotations

import itertools
import math
import os
from pathlib import Path

import networkx as nx
import numpy as np
import pytest
import shapely
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from shapely.geometry import MultiPolygon, Polygon, box

from fleet.engine.safety import check_steps
from fleet.floor import Floor, compile_floor, convex_pieces, load_floor, parse_spec
from fleet.floor.build import free_space, speed_cells

MAPS = Path(__file__).resolve().parent.parent / "maps"
SHIPPED = ["paper_case3.toml", "bump_track.toml", "shop_floor.toml"]


def spec_of(extra: str = "", clearance: float = 0.0, default: float = 1.0):
    """A 20 x 10 m floor plus whatever TOML `extra` adds."""
    import tomllib

    text = (
        f'[floor]\nname = "t"\nrect = [0, 0, 20, 10]\ndefault_v_max = {default}\n'
        f"clearance = {clearance}\n{extra}"
    )
    return parse_spec(tomllib.loads(text), "test.toml")


def assert_tiles(pieces: list[Polygon], area: Polygon | MultiPolygon, tol: float = 1e-6) -> None:
    """Pieces are convex, pairwise interior-disjoint and cover `area` exactly."""
    for p in pieces:
        assert p.is_valid and not p.interiors
        assert abs(p.convex_hull.area - p.area) < 1e-9, p.wkt
    union = shapely.union_all(pieces)
    assert abs(sum(p.area for p in pieces) - area.area) < tol
    assert union.symmetric_difference(area).area < tol
    tree = shapely.STRtree(pieces)
    for i, j in zip(*tree.query(pieces, predicate="intersects"), strict=True):
        if i < j:
            assert pieces[i].intersection(pieces[j]).area < 1e-9


# -- shipped maps -------------------------------------------------------------------------------


@pytest.fixture(scope="module", params=SHIPPED)
def shipped(request):
    return load_floor(MAPS / request.param)


def test_shipped_map_regions_tile_the_free_space(shipped):
    assert_tiles([r.polygon for r in shipped.regions], shipped.free_space)
    # ... which is the configuration space of the map (boundary shrunk, machines grown) up to
    # the 1e-6 m grid the set operations snap to.
    cspace = free_space(shipped.spec)
    assert shipped.free_space.symmetric_difference(cspace).area < 1e-6
    assert shipped.free_space.hausdorff_distance(cspace) < 2e-6


def test_shipped_map_hrep_agrees_with_shapely(shipped):
    rng = np.random.default_rng(7)
    x0, y0, x1, y1 = shipped.bounds
    xy = np.column_stack([rng.uniform(x0, x1, 2000), rng.uniform(y0, y1, 2000)])
    pts = shapely.points(xy)
    for r in shipped.regions:
        # Points within a hair of an edge may fall either way; compare the rest.
        inside = shapely.contains(r.polygon, pts)
        near = shapely.dwithin(r.polygon.boundary, pts, 1e-6)
        hrep = np.all(xy @ r.A.T <= r.b, axis=1)
        assert np.array_equal(hrep[~near], inside[~near])
        assert np.allclose(np.linalg.norm(r.A, axis=1), 1.0)
    located = shipped.locate_many(xy) >= 0
    free = shapely.covers(shipped.free_space, pts)
    edge = shapely.dwithin(shipped.free_space.boundary, pts, 1e-6)
    assert np.array_equal(located[~edge], free[~edge])


def test_shipped_map_is_connected_and_every_station_reachable(shipped):
    assert nx.is_connected(shipped.graph)
    for s in shipped.spec.stations:
        assert shipped.locate(s.x, s.y) is not None, s.name


def test_shipped_map_region_counts():
    counts = {name: len(load_floor(MAPS / name).regions) for name in SHIPPED}
    assert 30 <= counts["paper_case3.toml"] <= 50
    assert counts["bump_track.toml"] == 2  # the two legs of the L
    assert counts["shop_floor.toml"] >= 60


def test_paper_case3_straight_line_is_blocked_and_limits_are_the_papers():
    floor = load_floor(MAPS / "paper_case3.toml")
    start, goal = floor.station("start"), floor.station("goal")
    line = shapely.LineString([(start.x, start.y), (goal.x, goal.y)])
    assert not floor.free_space.covers(line)
    assert {r.v_max for r in floor.regions} == {(0.4, 0.4), (0.8, 0.8), (1.0, 1.0)}
    assert floor.bounds == (-110.0, -30.0, 10.0, 25.0)


def test_shop_floor_has_what_the_brief_promises():
    floor = load_floor(MAPS / "shop_floor.toml")
    spec = floor.spec
    assert len(spec.obstacles) >= 8 and len(spec.stations) >= 6 and len(spec.rough_areas) >= 2
    assert sum(s.kind == "depot" for s in spec.stations) == 2
    assert any(len(o.polygon.exterior.coords) - 1 > 4 for o in spec.obstacles)  # not all boxes
    assert spec.clearance == 0.4
    x0, y0, x1, y1 = floor.bounds
    assert x1 - x0 >= 60 and y1 - y0 >= 40


# -- configuration space and speed cells --------------------------------------------------------


def test_clearance_shrinks_the_boundary_and_grows_obstacles_with_mitred_corners():
    obstacle = '[[obstacles]]\nname = "m"\nrect = [8, 4, 12, 6]\n'
    bare = compile_floor(spec_of(obstacle, clearance=0.0))
    wide = compile_floor(spec_of(obstacle, clearance=0.5))
    assert bare.free_space.area == pytest.approx(20 * 10 - 4 * 2)
    # Mitred growth keeps square corners: (4 + 1) x (2 + 1) instead of a rounded rectangle.
    assert wide.free_space.area == pytest.approx(19 * 9 - 5 * 3, abs=1e-6)
    assert bare.is_free(7.7, 5) and not wide.is_free(7.7, 5)
    assert not wide.is_free(7.6, 3.6)  # in the mitred corner, 0.57 m from the machine's corner
    assert bare.is_free(0.2, 5) and not wide.is_free(0.2, 5)


def test_lowest_limit_wins_per_axis_where_zones_overlap():
    zones = (
        '[[zones]]\nname = "a"\nrect = [2, 2, 10, 8]\nv_max = [0.5, 1.0]\n'
        '[[zones]]\nname = "b"\nrect = [6, 2, 14, 8]\nv_max = [1.0, 0.3]\n'
        '[[zones]]\nname = "fast"\nrect = [16, 2, 19, 8]\nv_max = 2.0\n'
    )
    floor = compile_floor(spec_of(zones))
    assert floor.v_max_at(4, 5) == (0.5, 1.0)
    assert floor.v_max_at(8, 5) == (0.5, 0.3)
    assert floor.v_max_at(12, 5) == (1.0, 0.3)
    assert floor.v_max_at(1, 1) == (1.0, 1.0)
    assert floor.v_max_at(17, 5) == (2.0, 2.0)  # a zone may raise the limit above the default
    assert floor.regions[floor.locate(4, 5)].zone == "a"
    assert floor.regions[floor.locate(12, 5)].zone == "b"
    assert floor.regions[floor.locate(1, 1)].zone is None
    assert_tiles([r.polygon for r in floor.regions], floor.free_space)


def test_cells_with_equal_limits_merge():
    zones = (
        '[[zones]]\nname = "a"\nrect = [2, 2, 10, 8]\nv_max = 0.4\n'
        '[[zones]]\nname = "b"\nrect = [6, 2, 14, 8]\nv_max = 0.4\n'
    )
    spec = spec_of(zones)
    cells = speed_cells(spec.boundary, spec.zones, spec.default_v_max)
    assert [v for v, _ in cells] == [(0.4, 0.4), (1.0, 1.0)]
    assert cells[0][1].equals(box(2, 2, 14, 8))
    # The merged 0.4 cell is one rectangle, so one region.
    floor = compile_floor(spec)
    assert sum(r.v_max == (0.4, 0.4) for r in floor.regions) == 1


def test_stacked_rings_keep_the_inner_limit():
    text = (
        '[[obstacles]]\nname = "m"\nrect = [8, 4, 12, 6]\n'
        '[[zones]]\nname = "ring"\naround = "slow"\nmargin = 1.0\nv_max = 0.8\n'
        '[[zones]]\nname = "slow"\naround = "m"\nmargin = 1.0\nv_max = 0.4\n'
    )
    floor = compile_floor(spec_of(text))
    assert floor.v_max_at(7.5, 5) == (0.4, 0.4)
    assert floor.v_max_at(6.5, 5) == (0.8, 0.8)
    assert floor.v_max_at(5.5, 5) == (1.0, 1.0)
    assert floor.v_max_at(6.1, 2.1) == (0.8, 0.8)  # mitred: the ring keeps square corners
    assert floor.spec.zones[0].polygon.equals(box(6, 2, 14, 8))
    assert {r.zone for r in floor.regions} == {"slow", "ring", None}


def test_around_zone_is_clipped_to_the_boundary():
    text = (
        '[[obstacles]]\nname = "m"\nrect = [0, 0, 2, 2]\n'
        '[[zones]]\nname = "z"\naround = "m"\nmargin = 1.0\nv_max = 0.4\n'
    )
    spec = spec_of(text)
    assert spec.zones[0].polygon.equals(box(0, 0, 3, 3))


def test_station_in_a_grown_corner_is_rejected_when_compiling():
    from fleet.errors import MapError

    text = (
        '[[obstacles]]\nname = "m"\nrect = [8, 4, 12, 6]\n'
        '[[stations]]\nname = "s"\nat = [7.6, 3.6]\n'  # 0.57 m from the corner, 0.4 from edges
    )
    spec = spec_of(text, clearance=0.45)
    with pytest.raises(MapError) as info:
        compile_floor(spec)
    err = info.value
    assert err.source == "test.toml" and err.field == "stations[0] (s).at"
    assert "[7.6, 3.6]" in str(err) and "'m'" in str(err) and "mitred" in str(err)


def test_clearance_leaving_no_free_space_is_an_error():
    from fleet.errors import MapError

    with pytest.raises(MapError) as info:
        compile_floor(spec_of(clearance=5.0))
    assert info.value.field == "floor.clearance" and "5.0" in str(info.value)


def test_load_floor_caches_until_the_file_changes(tmp_path):
    src = (MAPS / "bump_track.toml").read_text()
    path = tmp_path / "m.toml"
    path.write_text(src)
    first = load_floor(path)
    assert load_floor(path) is first
    assert load_floor(path, cache=False) is not first
    st_ = path.stat()
    path.write_text(src.replace('name = "Bump track (case study 2)"', 'name = "changed"'))
    os.utime(path, ns=(st_.st_atime_ns, st_.st_mtime_ns + 1_000_000_000))
    second = load_floor(path)
    assert second is not first and second.name == "changed"


# -- convex decomposition -----------------------------------------------------------------------


def test_rectangle_with_a_hole_gives_four_pieces():
    area = box(0, 0, 10, 10).difference(box(4, 4, 6, 6))
    pieces = convex_pieces(area)
    assert len(pieces) == 4
    assert_tiles(pieces, area)


def test_convex_input_is_one_piece_and_l_shape_two():
    assert len(convex_pieces(box(0, 0, 3, 1))) == 1
    ell = Polygon([(0, 0), (4, 0), (4, 1), (1, 1), (1, 4), (0, 4)])
    assert len(convex_pieces(ell)) == 2


def test_multipolygon_pieces_stay_in_their_parts():
    area = MultiPolygon([box(0, 0, 1, 1), Polygon([(2, 0), (4, 0), (4, 2), (3, 1), (2, 2)])])
    pieces = convex_pieces(area)
    assert len(pieces) == 3
    assert_tiles(pieces, area)


def test_collinear_vertices_are_dropped_from_pieces():
    square = Polygon([(0, 0), (1, 0), (2, 0), (2, 2), (0, 2)])
    (piece,) = convex_pieces(square)
    assert len(piece.exterior.coords) == 5


def _star(cx: float, cy: float, radii: list[float], phase: float) -> Polygon:
    n = len(radii)
    pts = [
        (
            round(cx + r * math.cos(phase + 2 * math.pi * k / n), 3),
            round(cy + r * math.sin(phase + 2 * math.pi * k / n), 3),
        )
        for k, r in enumerate(radii)
    ]
    return Polygon(pts)


@st.composite
def polygons_with_holes(draw):
    """Star-shaped shells with up to three star-shaped holes, coordinates on a 1 mm grid."""
    shell = _star(
        0, 0, draw(st.lists(st.floats(4, 10), min_size=3, max_size=14)), draw(st.floats(0, 6.3))
    )
    holes: list[Polygon] = []
    for _ in range(draw(st.integers(0, 3))):
        hole = _star(
            draw(st.floats(-3, 3)),
            draw(st.floats(-3, 3)),
            draw(st.lists(st.floats(0.3, 1.2), min_size=3, max_size=8)),
            draw(st.floats(0, 6.3)),
        )
        if (
            hole.is_valid
            and shell.buffer(-0.05).contains(hole)
            and all(hole.distance(h) > 0.05 for h in holes)
        ):
            holes.append(hole)
    poly = Polygon(shell.exterior.coords, [h.exterior.coords for h in holes])
    return poly


@settings(max_examples=150, deadline=None)
@given(polygons_with_holes())
def test_convex_pieces_tile_any_polygon_with_holes(poly):
    assume(poly.is_valid)  # rounding can make two vertices of a small star coincide
    pieces = convex_pieces(poly)
    assert_tiles(pieces, poly, tol=1e-6)
    # Never worse than the triangulation it starts from.
    n = len(poly.exterior.coords) - 1 + sum(len(h.coords) - 1 for h in poly.interiors)
    assert len(pieces) <= n - 2 + 2 * len(poly.interiors)


def test_pieces_of_speed_cells_do_not_overlap_across_cells():
    floor = load_floor(MAPS / "shop_floor.toml")
    polys = [r.polygon for r in floor.regions]
    for a, b in itertools.combinations(range(len(polys)), 2):
        if polys[a].intersects(polys[b]):
            assert polys[a].intersection(polys[b]).area < 1e-9


def test_every_region_edge_lies_in_the_free_space_the_checker_uses():
    # Zone edges crossing a slanted machine edge create vertices that the 1e-6 m grid moves;
    # the free space must be exactly what the regions cover, or a controller hugging a region's
    # A, b would be charged with obstacle incursions.
    spec = parse_spec(
        {
            "floor": {"name": "t", "rect": [0, 0, 20, 20], "default_v_max": 1.0, "clearance": 0.3},
            "obstacles": [{"name": "m", "polygon": [[5.1, 5.3], [15.7, 6.9], [9.3, 13.1]]}],
            "zones": [
                {"name": f"z{i}", "rect": [0, 0, x, 20], "v_max": v}
                for i, (x, v) in enumerate([(7.77, 0.5), (11.13, 0.7), (13.3, 0.9)])
            ],
        },
        "t.toml",
    )
    floor = compile_floor(spec)
    vertices = [p for r in floor.regions for p in r.polygon.exterior.coords]
    assert max(floor.free_space.distance(shapely.Point(p)) for p in vertices) == 0.0
    for r in floor.regions:
        ring = np.asarray(r.polygon.exterior.coords)
        for a, b in zip(ring[:-1], ring[1:], strict=True):
            xy = np.linspace(a, b, 5)
            v = np.tile((b - a) / 4 / 10.0, (5, 1))  # slow enough for any zone
            v[-1] = 0
            assert check_steps(floor, np.arange(5) * 10.0, xy, v, "edge") == []


def test_a_loaded_floor_is_read_only_and_named_by_its_resolved_path():
    floor = load_floor(MAPS / "paper_case3.toml")
    assert floor.source == str((MAPS / "paper_case3.toml").resolve())
    with pytest.raises(ValueError, match="read-only"):
        floor.regions[0].b[0] = 0.0
    with pytest.raises(nx.NetworkXError, match="Frozen"):
        floor.graph.add_edge(0, 1)


def test_v_max_at_a_shared_boundary_takes_each_axis_lowest():
    floor = compile_floor(
        spec_of('[[zones]]\nname = "z"\nrect = [0, 0, 5, 10]\nv_max = [0.4, 2.0]\n', default=1.0)
    )
    assert floor.v_max_at(2, 5) == (0.4, 2.0)
    assert floor.v_max_at(5, 5) == (0.4, 1.0)  # on the zone's edge: both sides apply
    assert floor.v_max_at(8, 5) == (1.0, 1.0)
    assert floor.v_max_at(30, 5) is None


def test_regions_meeting_at_a_t_junction_are_adjacent():
    # Two pieces of the detour of fuzz case s21-0819: the upper one's edge runs 1.42 m along
    # the lower one's 1.95 m edge from their common corner, and ends on it (exactly, in
    # decimal; off it by rounding in binary). Their boundaries' exact intersection is a point.
    upper = Polygon(
        [(-20.382403, 55.139899), (-20.6963, 54.826002), (-20.898278, 54.338384),
         (-19.894784, 55.341878)]
    )  # fmt: skip
    lower = Polygon(
        [(-19.016381, 55.992048), (-19.521578, 55.715084), (-20.898278, 54.338384),
         (-22.151266, 48.196531)]
    )  # fmt: skip
    assert upper.boundary.intersection(lower.boundary).length == 0.0
    floor = Floor.from_regions(spec_of(), [(upper, (1.0, 1.0), None), (lower, (1.0, 1.0), None)])
    assert floor.graph.has_edge(0, 1)
    portal = floor.graph.edges[0, 1]["portal"]
    assert portal.length == pytest.approx(
        math.dist((-20.898278, 54.338384), (-19.894784, 55.341878))
    )


def test_a_detour_round_two_robots_at_rest_keeps_the_floor_connected():
    # Fuzz case s21-0819 (tests/path_cases/README.md): r02 at rest with r01 and r03 beside it;
    # the detour round them must leave r02 a way home across the open floor.
    from fleet.paths import PathPlanner
    from fleet_plugins.follower.yielding import Detour

    base = load_floor(Path(__file__).parent / "path_cases" / "detour_round_two_robots.toml")
    blockers = [("r01", -20.6463, 56.4666, 0.479), ("r03", -22.023000576850887, 55.0899, 0.479)]
    start, home = (-20.32971080597771, 55.08477118148952), (-9.4548, 47.1595)
    detour = Detour.build(base, blockers, 0.479, 0.3687005768508881, start, 0.5)
    assert detour.floor is not None
    assert nx.number_connected_components(detour.floor.graph) == nx.number_connected_components(
        base.graph
    )
    path = PathPlanner(detour.floor, v_max=0.78, a_max=0.5).path(start, home)
    assert path.travel_time > 0
