"""The garbage collector during a run (`fleet.engine.collector`): less often, still on, and
as it was afterwards."""

from __future__ import annotations

import gc
import weakref

from fleet.engine import World
from fleet.engine.collector import YOUNG_THRESHOLD, fewer_collections
from fleet.scenario import REPO_ROOT, load_scenario


class Node:
    def __init__(self) -> None:
        self.other: Node | None = None


def test_collections_are_fewer_inside_and_restored_after_nested_blocks():
    before = gc.get_threshold()
    assert gc.get_freeze_count() == 0
    with fewer_collections():
        assert gc.get_threshold()[0] == max(YOUNG_THRESHOLD, before[0])
        assert gc.get_freeze_count() > 0  # what was alive is frozen
        with fewer_collections():
            assert gc.get_threshold()[0] == max(YOUNG_THRESHOLD, before[0])
        assert gc.get_threshold()[0] == max(YOUNG_THRESHOLD, before[0])  # the outer one holds
        # Cyclic garbage made inside is still collected.
        a, b = Node(), Node()
        a.other, b.other = b, a
        gone = weakref.ref(a)
        del a, b
        gc.collect()
        assert gone() is None
    assert gc.get_threshold() == before
    assert gc.get_freeze_count() == 0


def test_a_run_collects_less_often_and_leaves_the_collector_as_it_found_it():
    scenario = load_scenario(REPO_ROOT / "scenarios" / "default.toml").override(
        robots=2, duration=20.0
    )
    before = gc.get_threshold()
    seen = []
    World(scenario).run(progress=lambda t: seen.append(gc.get_threshold()[0]))
    assert seen and all(s == max(YOUNG_THRESHOLD, before[0]) for s in seen)
    assert gc.get_threshold() == before
    assert gc.get_freeze_count() == 0


def test_objects_the_process_froze_itself_stay_frozen():
    kept = [Node() for _ in range(10)]
    gc.freeze()
    try:
        with fewer_collections():
            assert gc.get_threshold()[0] >= YOUNG_THRESHOLD
        assert gc.get_freeze_count() > 0  # not thawed when the run's block ended
    finally:
        gc.unfreeze()
    assert kept
