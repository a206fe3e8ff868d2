"""Input parsing time: every scenario in scenarios/ and every map in maps/, medians.

For each file it prints two medians over --repeats rounds, in microseconds of this process's CPU
time (on a shared machine wall time would also measure the neighbours):

- ``load``: the whole read (`load_scenario` / `load_spec`: the file, TOML, checks, the config
  objects; a scenario also checks that its map, parts and calibration files exist);
- ``check``: the checks alone on the already-parsed TOML (`parse_scenario` / `parse_spec`).

Only the public reading functions are called, so the same script measures any version of the
readers: run it from another checkout, or with PYTHONPATH pointing at one, to compare. Nothing
here is asserted: the figures go in notes.

    python scripts/bench_inputs.py [--repeats 200]
"""

from __future__ import annotations

import argparse
import statistics
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

from fleet.floor import load_spec, parse_spec
from fleet.scenario import load_scenario, parse_scenario

#: The checkout this script is in: its scenarios/ and maps/ are measured, whichever `fleet` runs.
REPO_ROOT = Path(__file__).resolve().parents[1]


def median_us(work: Callable[[], object], repeats: int) -> float:
    """Median CPU time of `work` in microseconds, after one warm-up call."""
    work()
    times = []
    for _ in range(repeats):
        start = time.process_time_ns()
        work()
        times.append(time.process_time_ns() - start)
    return statistics.median(times) / 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=200, help="rounds per file (default 200)")
    args = parser.parse_args()

    print(f"{'file':<36} {'load us':>9} {'check us':>9}")
    totals = [0.0, 0.0]
    for path in sorted((REPO_ROOT / "scenarios").glob("*.toml")):
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
        figures = (
            median_us(lambda p=path: load_scenario(p), args.repeats),
            median_us(lambda r=raw, p=path: parse_scenario(r, p), args.repeats),
        )
        totals = [t + f for t, f in zip(totals, figures, strict=True)]
        print(f"{'scenarios/' + path.name:<36} {figures[0]:>9.0f} {figures[1]:>9.0f}")
    for path in sorted((REPO_ROOT / "maps").glob("*.toml")):
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
        figures = (
            median_us(lambda p=path: load_spec(p), args.repeats),
            median_us(lambda r=raw, p=path: parse_spec(r, str(p)), args.repeats),
        )
        totals = [t + f for t, f in zip(totals, figures, strict=True)]
        print(f"{'maps/' + path.name:<36} {figures[0]:>9.0f} {figures[1]:>9.0f}")
    print(f"{'sum of medians':<36} {totals[0]:>9.0f} {totals[1]:>9.0f}")


if __name__ == "__main__":
    main()
