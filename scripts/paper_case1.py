"""Case studies 1 and 2 of the paper, refitted: the QSP from Table 1, the vibration from Table 2.

Fits the shipped calibration (`fleet.printing.quality.default_model`), prints the per-axis lines,
the speed cap per task at the tolerances, the tolerance the paper's caps imply, the vibration fit
and what the model predicts for every Table 2 run beside what the paper measured; writes ``qsp.png``
(data, fitted lines, tolerance band), ``qsp_fit.csv`` and ``table2_fit.csv`` to --out.

    python scripts/paper_case1.py [--out runs/paper_case1] [--tolerance 0.05]
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from fleet.printing import PAPER_CAPS
from fleet.printing.quality import ALL, DEFAULT_TOLERANCE_MM, check_runs, data_file, default_model
from fleet.view.figures import KIND_COLOURS

_AXIS_COLOURS = {"height": "#1f77b4", "width": "#ff7f0e", "depth": "#2ca02c"}
_KINDS = ("contour", "infill", "support")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("runs/paper_case1"))
    ap.add_argument(
        "--tolerance", type=float, default=DEFAULT_TOLERANCE_MM, help="mm, every task kind"
    )
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    model = default_model()
    profile = model.profile(ALL)
    print("Table 1: |error| = a v + b per axis (least squares, 12 points each)")
    print(f"  {'axis':<8} {'a (mm per m/s)':>15} {'b (mm)':>9} {'v at tol (m/s)':>15}")
    for axis, line in profile.lines.items():
        print(f"  {axis:<8} {line.a:>15.4f} {line.b:>9.4f} {line.max_speed(args.tolerance):>15.3f}")

    tols = dict.fromkeys(_KINDS, args.tolerance)
    caps = model.caps(tols)
    implied = model.implied_tolerances(PAPER_CAPS)
    print(
        f"\nPer task at tolerance {args.tolerance:g} mm (Table 1 has no task column: one profile)"
    )
    print(
        f"  {'task':<8} {'cap (m/s)':>10} {'paper cap':>10} {'tol implied by paper cap (mm)':>30}"
    )
    for kind in _KINDS:
        print(f"  {kind:<8} {caps[kind]:>10.3f} {PAPER_CAPS[kind]:>10.1f} {implied[kind]:>30.4f}")

    vib = model.vibration
    print(
        f"\nTable 2 vibration fit: kick = severity * {vib.coef_mm:.3g} mm * "
        f"exp({vib.rate_per_mps:.2f} * crossing speed); failure at {vib.failure_mm:.2f} mm"
    )
    checks = check_runs(model)
    head = (
        f"  {'run':<8} {'paper':<7} {'cross':>5} {'mean v':>6} {'worst':>6} {'q(mean)':>7} "
        f"{'resid':>6} {'kick':>7} {'pred':>7} {'model':<9} {'max-metric':<10}"
    )
    print(head)
    for c in checks:
        print(
            f"  {c.run:<8} {c.outcome:<7} {c.crossing_mps:>5.2f} {_f(c.mean_speed, 6, 3)} "
            f"{_f(c.measured_mm, 6, 2)} {_f(c.qsp_mm, 7, 4)} {_f(c.residual_mm, 6, 3)} "
            f"{c.kick_mm:>7.3f} {_f(c.predicted_mm, 7, 3)} {c.predicted:<9} {c.predicted_max:<10}"
        )

    _write_fits(args.out, profile, checks)
    png = args.out / "qsp.png"
    _qsp_figure(profile, args.tolerance, caps).savefig(png, dpi=150)
    print(f"\nwrote {png}, {args.out / 'qsp_fit.csv'}, {args.out / 'table2_fit.csv'}")


def _f(value: float, width: int, digits: int) -> str:
    return f"{'-':>{width}}" if math.isnan(value) else f"{value:>{width}.{digits}f}"


def _write_fits(out: Path, profile, checks) -> None:
    with open(out / "qsp_fit.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["task", "axis", "a_mm_per_mps", "b_mm"])
        for axis, line in profile.lines.items():
            w.writerow([ALL, axis, f"{line.a:.6g}", f"{line.b:.6g}"])
    with open(out / "table2_fit.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            [
                "run",
                "paper_outcome",
                "crossing_mps",
                "mean_speed_mps",
                "measured_mm",
                "qsp_mm",
                "residual_mm",
                "kick_mm",
                "predicted_mm",
                "predicted",
                "predicted_max_metric",
            ]
        )
        for c in checks:
            w.writerow(
                [
                    c.run,
                    c.outcome,
                    c.crossing_mps,
                    *(
                        "" if math.isnan(x) else f"{x:.6g}"
                        for x in (c.mean_speed, c.measured_mm, c.qsp_mm, c.residual_mm)
                    ),
                    f"{c.kick_mm:.6g}",
                    "" if math.isnan(c.predicted_mm) else f"{c.predicted_mm:.6g}",
                    str(c.predicted),
                    str(c.predicted_max),
                ]
            )


def _qsp_figure(profile, tol: float, caps: dict[str, float]) -> Figure:
    fig = Figure(figsize=(7.0, 4.5), layout="constrained")
    FigureCanvasAgg(fig)  # attaches itself: savefig renders with Agg, no pyplot
    ax = fig.add_subplot()
    with open(data_file("table1.csv"), newline="") as f:
        rows = list(csv.DictReader(f))
    v = np.linspace(0.0, 1.05, 200)
    for i, (axis, line) in enumerate(profile.lines.items()):
        colour = _AXIS_COLOURS.get(axis, "#555555")
        # Axes measured at the same speed are nudged apart so equal errors stay visible.
        dx = 0.012 * (i - (len(profile.lines) - 1) / 2)
        pts = [
            (float(r["speed_mps"]) + dx, abs(float(r["error_mm"])))
            for r in rows
            if r["axis"] == axis
        ]
        ax.scatter(*zip(*pts, strict=True), color=colour, s=18, label=f"{axis} |error|")
        ax.plot(v, line.error(v), ":", color=colour, label=f"{axis}: {line.a:.3f} v + {line.b:.3f}")
    ax.plot(v, profile.error(v), "k-", lw=1.6, label="QSP (largest axis)")
    ax.axhspan(0.0, tol, color="#9ecae1", alpha=0.35, label=f"tolerance {tol:g} mm")
    cap = caps["contour"]
    if math.isfinite(cap):
        ax.axvline(cap, color="k", lw=0.8, ls="--", label=f"cap at tolerance: {cap:.3f} m/s")
    for kind, paper_cap in PAPER_CAPS.items():
        ax.axvline(
            paper_cap, color=KIND_COLOURS[kind], lw=0.8, alpha=0.7, label=f"paper {kind} cap"
        )
    ax.set_xlabel("base speed v (m/s)")
    ax.set_ylabel("dimensional error (mm)")
    ax.set_title("Case study 1: quality-speed profile (Table 1)")
    ax.set_xlim(-0.02, 1.05)
    ax.set_ylim(0.0, None)
    ax.legend(fontsize=7, loc="upper left")
    return fig


if __name__ == "__main__":
    main()
