"""Golden runs: a handful of shipped scenarios whose trajectory digests must not change.

The digest is a sha256 over every robot's exact samples, so any change in behaviour, however
small, shows here. A change that alters behaviour on purpose records the new digests in a commit
of its own that says why:

    python -m tests.test_golden --record

Digests depend on the exact versions of numpy and HiGHS, so they are compared only in an
environment that holds exactly `requirements.lock` (`make test`, CI); elsewhere (`make
test-latest`) these tests skip, naming the differences.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import pytest

from fleet.engine import World
from fleet.scenario import REPO_ROOT, load_scenario
from tests.scripts import load_script

GOLDEN = Path(__file__).with_name("golden_digests.json")

#: name -> (scenario file, overrides, workers). Follower and MPC, one robot and several, agents
#: in this process and in two worker processes.
CASES: dict[str, tuple[str, dict[str, Any], int]] = {
    "follower-default-6-robots": ("default.toml", {"duration": 2400.0}, 0),
    "follower-fleet-6-robots-2-workers": ("fleet.toml", {"robots": 6, "duration": 90.0}, 2),
    "mpc-case3-s2-1-robot": ("paper_case3_s2.toml", {}, 0),
    "mpc-fleet-4-robots": ("fleet.toml", {"robots": 4, "duration": 90.0, "controller": "mpc"}, 0),
    "mpc-fleet-4-robots-2-workers": (
        "fleet.toml",
        {"robots": 4, "duration": 90.0, "controller": "mpc"},
        2,
    ),
}


def run_case(name: str) -> dict[str, Any]:
    file, overrides, workers = CASES[name]
    scenario = load_scenario(REPO_ROOT / "scenarios" / file).override(**overrides)
    summary = World(scenario, workers=workers).run().summary
    return {
        "digest": summary["digest"],
        "completed": summary["jobs"]["completed"],
        "termination": summary.get("solver", {}).get("termination", {}),
    }


def lock_differences() -> list[str]:
    check_lock = load_script("check_lock")
    pins = check_lock.locked(REPO_ROOT / "requirements.lock")
    return check_lock.differences(pins, check_lock.installed())


@pytest.fixture(scope="module")
def golden() -> dict[str, Any]:
    differences = lock_differences()
    if differences:
        pytest.skip("not the lock's versions: " + "; ".join(differences[:3]))
    return json.loads(GOLDEN.read_text(encoding="utf-8"))


@pytest.mark.parametrize("name", sorted(CASES))
def test_behaviour_matches_the_recorded_run(name: str, golden: dict[str, Any]) -> None:
    got = run_case(name)
    # An MPC solve cut short by its time limit depends on the machine's speed, not the code.
    assert set(got["termination"]) <= {"optimal"}, got["termination"]
    want = golden[name]
    assert got["completed"] == want["completed"]
    assert got["digest"] == want["digest"], (
        f"{name}: behaviour changed; if on purpose, record it (see the module docstring)"
    )


def test_every_case_is_recorded() -> None:
    assert set(json.loads(GOLDEN.read_text(encoding="utf-8"))) == set(CASES)


if __name__ == "__main__":
    if sys.argv[1:] != ["--record"]:
        raise SystemExit("usage: python -m tests.test_golden --record")
    recorded = {}
    for case in sorted(CASES):
        result = run_case(case)
        recorded[case] = {"digest": result["digest"], "completed": result["completed"]}
        print(case, recorded[case])
    GOLDEN.write_text(json.dumps(recorded, indent=2) + "\n", encoding="utf-8")
