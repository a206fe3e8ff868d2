"""Figures of a run's KPIs over time, drawn from its run directory (never by re-running):

- ``states.png``: one stacked bar per robot, its share of the measured window in each state
  (``states.csv``; the states are `fleet.engine.activity`'s), fleet-wide shares in the legend;
- ``wip.png``: the queue (released, not assigned) and the WIP (released, neither delivered nor
  failed) over time as steps (``wip.csv``), with the warm-up left out of the KPIs and the one
  MSER-5 suggests marked (from ``summary.json``).

`fleet.view.figures.save_run_figures` writes them with the other figures when the run directory
has their files (runs written before they existed have not); `fleet.view.figures` imports this
module, so it reads its CSVs itself.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from fleet.errors import InputError

__all__ = [
    "STATES_PNG",
    "WIP_PNG",
    "STATE_COLOURS",
    "load_states",
    "load_wip",
    "states_figure",
    "wip_figure",
    "save_kpi_figures",
]

STATES_PNG = "states.png"
WIP_PNG = "wip.png"

#: One colour per robot state, in the order the bars stack them.
STATE_COLOURS: Mapping[str, str] = {
    "printing_driving": "#2ca02c",
    "printing_at_rest": "#98df8a",
    "driving_empty": "#1f77b4",
    "blocked": "#ff7f0e",
    "idle": "#c7c7c7",
    "charging": "#9467bd",
    "faulted": "#d62728",
}

_DPI = 150


def _rows(path: Path, columns: Sequence[str]) -> list[tuple[int, dict[str, str]]]:
    """A run CSV's rows as (line, row) after checking its header; `InputError` naming the file,
    the line and the column otherwise (as `fleet.view.figures.read_csv_rows`)."""
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            missing = [c for c in columns if c not in (reader.fieldnames or [])]
            if missing:
                raise InputError(
                    str(path), "header", ",".join(reader.fieldnames or []), f"lacks {missing}"
                )
            return [(reader.line_num, row) for row in reader]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputError(
            str(path), "(file)", str(exc), "must be the CSV `fleet run` writes"
        ) from None


def _number(path: Path, line: int, column: str, text: str | None) -> float:
    try:
        value = float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        value = math.nan
    if not math.isfinite(value):
        raise InputError(str(path), f"line {line}, {column}", text, "must be a finite number")
    return value


def load_states(path: Path) -> dict[str, dict[str, float]]:
    """``states.csv`` as {robot: {state: seconds}}, robots in the file's order."""
    path = Path(path)
    out: dict[str, dict[str, float]] = {}
    for line, row in _rows(path, ("robot", "state", "seconds")):
        seconds = _number(path, line, "seconds", row["seconds"])
        out.setdefault(row["robot"], {})[row["state"]] = seconds
    return out


def load_wip(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``wip.csv`` as arrays (t, queue, wip): each value holds from its time to the next."""
    path = Path(path)
    rows = _rows(path, ("t", "queue", "wip"))
    cols = [
        np.array([_number(path, line, c, row[c]) for line, row in rows])
        for c in ("t", "queue", "wip")
    ]
    return cols[0], cols[1], cols[2]


def states_figure(states: Mapping[str, Mapping[str, float]], *, title: str = "") -> Figure:
    """One horizontal bar per robot, stacked by state, as shares of its measured time."""
    robots = list(states)
    fig = _figure((8.0, 1.6 + 0.35 * max(len(robots), 1)))
    ax = fig.add_subplot()
    totals = np.array([sum(states[r].values()) for r in robots], dtype=float)
    safe = np.where(totals > 0, totals, 1.0)
    fleet_total = float(totals.sum()) or 1.0
    left = np.zeros(len(robots))
    for state, colour in STATE_COLOURS.items():
        secs = np.array([states[r].get(state, 0.0) for r in robots], dtype=float)
        share = secs / safe
        label = f"{state.replace('_', ' ')} ({100 * secs.sum() / fleet_total:.0f} %)"
        ax.barh(robots, share, left=left, color=colour, label=label, height=0.7)
        left += share
    ax.set_xlim(0, 1)
    ax.invert_yaxis()  # the first robot on top
    ax.set_xlabel("share of the measured time")
    ax.xaxis.set_major_formatter(lambda x, _pos: f"{100 * x:.0f} %")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small", title="fleet")
    ax.set_title(title or "Robot states")
    return fig


def wip_figure(
    t: Sequence[float],
    queue: Sequence[float],
    wip: Sequence[float],
    *,
    t_end: float,
    warmup_s: float = 0.0,
    suggested_s: float | None = None,
    title: str = "",
) -> Figure:
    """The queue and the WIP over time as steps, with the warm-up and MSER-5's suggestion."""
    fig = _figure((8.0, 3.6))
    ax = fig.add_subplot()
    tt = np.append(np.asarray(t, dtype=float), max(t_end, float(t[-1]) if len(t) else 0.0))
    for values, label, colour in ((wip, "WIP", "#1f77b4"), (queue, "queue", "#ff7f0e")):
        v = np.asarray(values, dtype=float)
        ax.step(tt, np.append(v, v[-1] if v.size else 0.0), where="post", label=label, c=colour)
    if warmup_s > 0:
        ax.axvspan(0.0, warmup_s, color="#dddddd", label="warm-up (left out)")
    if suggested_s is not None:
        ax.axvline(suggested_s, ls="--", c="k", lw=1, label=f"MSER-5: {suggested_s:.0f} s")
    ax.set_xlim(0, tt[-1] if tt[-1] > 0 else 1.0)
    ax.set_ylim(bottom=0)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("jobs")
    ax.legend(loc="upper left", fontsize="small")
    ax.set_title(title or "Queue and WIP")
    return fig


def save_kpi_figures(run_dir: Path, *, title: str = "", t_end: float | None = None) -> list[Path]:
    """Write ``states.png`` and ``wip.png`` into `run_dir` for those of ``states.csv`` and
    ``wip.csv`` it has; returns the files written."""
    run_dir = Path(run_dir)
    summary: dict[str, Any] = {}
    if (run_dir / "summary.json").is_file():
        summary = json.loads((run_dir / "summary.json").read_text(encoding="utf-8"))
    out = []
    if (run_dir / "states.csv").is_file():
        fig = states_figure(load_states(run_dir / "states.csv"), title=title)
        fig.savefig(run_dir / STATES_PNG, dpi=_DPI)
        out.append(run_dir / STATES_PNG)
    if (run_dir / "wip.csv").is_file():
        t, queue, wip = load_wip(run_dir / "wip.csv")
        end = t_end if t_end is not None else float(summary.get("sim_time_s") or t[-1])
        fig = wip_figure(
            t,
            queue,
            wip,
            t_end=end,
            warmup_s=float(summary.get("warmup_s") or 0.0),
            suggested_s=summary.get("suggested_warmup_s"),
            title=title,
        )
        fig.savefig(run_dir / WIP_PNG, dpi=_DPI)
        out.append(run_dir / WIP_PNG)
    return out


def _figure(size: tuple[float, float]) -> Figure:
    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    return fig
