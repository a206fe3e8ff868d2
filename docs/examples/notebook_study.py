"""A small study in notebook style with mambot-fleet's Python API (docs/api.md).

Run it whole (``python docs/examples/notebook_study.py``) or cell by cell in anything that
knows ``# %%`` cells (VS Code, Spyder, PyCharm, Jupytext). It needs no pandas; where pandas is
installed, every table goes into a data frame in one line. It takes about 15 s (6 s of
CPU) on a shared 2-core machine.
"""

# %% Load a scenario, with a few values changed by dotted key
import statistics

import fleet
from fleet.errors import ScenarioError
from fleet.scenario import REPO_ROOT  # the checkout; in your notebook, any path to a scenario

base = fleet.load_scenario(
    REPO_ROOT / "scenarios" / "default.toml",
    {"scenario.duration_s": 600, "jobs.parts": [], "jobs.rate_per_h": 120},
)
print(f"{base.name}: {base.robots[0].count} robots, {base.duration_s:g} s, seed {base.seed}")

# %% Change it in code: checked as a file is (a bad key or value names itself)
four = fleet.change(base, {"robots.count": 4, "scenario.seed": 3})
try:
    fleet.change(base, {"robots.count": 0})
except ScenarioError as exc:
    print(f"refused: {exc}")

# %% Run it: nothing is printed; the run directory is a temporary one unless out_dir is given
result = fleet.run(four)
s = result.summary
print(
    f"{s['robots']} robots: {s['jobs']['released']} jobs released, "
    f"{s['jobs']['completed']} delivered, {s['throughput_per_h']:.1f} jobs/h"
)
print("tables:", ", ".join(result.table_names))

# %% Its tables: typed columns, {column: [value, ...]}
jobs = result.table("jobs")
lead_times = [
    done - released
    for released, done in zip(jobs["released_s"], jobs["delivered_s"], strict=True)
    if done is not None
]
print(f"lead time: median {statistics.median(lead_times):.1f} s, max {max(lead_times):.1f} s")
first = result.rows("jobs")[0]
print("first job:", {k: first[k] for k in ("id", "robot", "released_s", "delivered_s")})
try:
    import pandas as pd  # not needed by mambot-fleet; one line makes a data frame

    print(pd.DataFrame(jobs).describe())
except ImportError:
    pass

# %% A tiny sweep over the fleet size, two seeds each, one cell after another in this process
study = fleet.sweep(base, grid={"robots": [2, 4]}, seeds=2, jobs=0)
print(f"{study.ok} cells ok, {study.failed} failed")
for row in study.rows:
    print(
        f"robots {row['robots']} seed {row['seed']}: {row['throughput_per_h']:.1f} jobs/h, "
        f"mean lead time {row['mean_lead_time_s']:.1f} s"
    )

# %% Compute something across the cells: the mean throughput per fleet size, and the p50
#    lead time over every delivered job of every cell (study.table("jobs") holds them all)
throughput: dict[int, list[float]] = {}
for row in study.rows:
    throughput.setdefault(row["robots"], []).append(row["throughput_per_h"])
mean_throughput = {n: statistics.mean(v) for n, v in sorted(throughput.items())}
all_jobs = study.table("jobs")
leads: dict[int, list[float]] = {}
for n, released, done in zip(
    all_jobs["robots"], all_jobs["released_s"], all_jobs["delivered_s"], strict=True
):
    if done is not None:
        leads.setdefault(n, []).append(done - released)
p50_lead = {n: statistics.median(v) for n, v in sorted(leads.items())}
for n in mean_throughput:
    print(f"{n} robots: {mean_throughput[n]:.1f} jobs/h on average, p50 lead {p50_lead[n]:.1f} s")
