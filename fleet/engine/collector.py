"""Python's cyclic garbage collector kept out of the way while a run is simulated.

A run makes objects by the million (observations, neighbours, plans, messages, samples) that
almost never form cycles, while the set-up (the floor, its portal graphs, the planners'
caches, the agents) stays alive throughout. With the collector's defaults a 1,000-robot busy
run spent over a third of its wall time in collections, most of it scanning the set-up's
objects again and again in full collections (docs/performance.md). `fewer_collections`
freezes what exists when the run starts (`gc.freeze`: never scanned until the run ends) and
collects the youngest generation every `YOUNG_THRESHOLD` allocations instead of 700. The
collector still runs: cyclic garbage is collected as before, only less often. What a run
computes does not depend on it.
"""

from __future__ import annotations

import gc
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["fewer_collections", "YOUNG_THRESHOLD"]

#: Allocations (less deallocations) of container objects between two collections of the
#: youngest generation while a run is simulated (Python's default is 700).
YOUNG_THRESHOLD = 20_000

_lock = threading.Lock()
_depth = 0
_saved: tuple[int, ...] = ()
_froze = False


@contextmanager
def fewer_collections() -> Iterator[None]:
    """Freeze the objects alive now and collect less often until the block ends; then
    restore the collector's thresholds and unfreeze. Runs nested or in threads at once share
    one such period: the first to start begins it, the last to end ends it."""
    global _depth, _saved, _froze
    with _lock:
        if _depth == 0:
            _saved = gc.get_threshold()
            # A process that froze objects itself (e.g. before forking) keeps them frozen:
            # unfreezing at the end would thaw its objects too, so leave freezing alone then.
            _froze = gc.get_freeze_count() == 0
            if _froze:
                gc.freeze()
            gc.set_threshold(max(YOUNG_THRESHOLD, _saved[0]), *_saved[1:])
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                gc.set_threshold(*_saved)
                if _froze:
                    gc.unfreeze()
