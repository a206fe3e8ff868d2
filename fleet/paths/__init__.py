"""Reference paths: the portal graph, A*, time-parameterised references, and their checks.

`PathPlanner` answers every "how do I get from here to there on this floor" question of the
engine and the plugins: the geometric path (A* over the region graph, string pulled), its
travel time, and a `Reference` a controller can track (speed profile from a HiGHS LP). This
room imports `fleet.floor`, `fleet.highs` and `fleet.errors`.

Its modules, one job each:

- `planner`: `PathPlanner`, the public face, which builds the parts below and caches answers;
- `results`: `Path` and `Reference`, the read-only answers;
- `limits`: zone speed limits along segments, and travel times at those limits;
- `graph`: the portal graph, A* over it and string pulling: the geometric path;
- `timing`: the time-parameterised reference, the HiGHS LP over its step speeds, its self-check.
"""

from fleet.paths.planner import CacheInfo, PathPlanner
from fleet.paths.results import Path, Reference

__all__ = ["PathPlanner", "Path", "Reference", "CacheInfo"]
