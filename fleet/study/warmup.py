"""The study report's warm-up note: what MSER-5 suggested for the study's runs.

Each run's summary.json carries ``suggested_warmup_s`` (MSER-5 on its WIP series,
`fleet.engine.warmup`) and the ``warmup_s`` it left out of its KPIs; the note gathers them so
that a study can be run again with a warm-up long enough for all its cells.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np

__all__ = ["warmup_lines"]


def warmup_lines(run_dirs: Iterable[Path | None]) -> list[str]:
    """Markdown lines for ``report.md``: a "Warm-up" section with the median and largest
    MSER-5 suggestion over the runs whose summary.json has one (none: no lines)."""
    suggested, used, at_limit = [], [], 0
    for run_dir in run_dirs:
        path = None if run_dir is None else Path(run_dir) / "summary.json"
        if path is None or not path.is_file():
            continue
        try:
            s = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        value = s.get("suggested_warmup_s")
        if not isinstance(value, int | float):
            continue
        suggested.append(float(value))
        used.append(float(s.get("warmup_s") or 0.0))
        at_limit += bool(s.get("suggested_warmup_at_limit"))
    if not suggested:
        return []
    most = max(suggested)
    lines = [
        "",
        "## Warm-up",
        "",
        f"MSER-5 on each run's WIP series suggests a warm-up of {np.median(suggested):.0f} s "
        f"(median) to {most:.0f} s (largest) over {len(suggested)} runs; the runs left out "
        f"{max(used):g} s (`[scenario] warmup_s`).",
    ]
    if at_limit:
        lines.append(
            f"In {at_limit} run(s) the suggestion is half the run, the search's limit: the WIP had "
            "not settled, so those runs are too short to judge; run longer."
        )
    elif most > max(used):
        lines.append(f"Set `warmup_s` to at least {most:.0f} s to leave the transient out.")
    return lines
