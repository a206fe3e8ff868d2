"""scripts/check_lock.py: the lock's pins for this platform, and every way an environment can
differ from them."""

import sys

from fleet.scenario import REPO_ROOT
from tests.scripts import load_script

check_lock = load_script("check_lock")

LOCK = """\
# header
numpy==2.4.6 ; python_full_version < '3.12' \\
    --hash=sha256:aa
numpy==2.5.5 ; python_full_version >= '3.12' \\
    --hash=sha256:bb
colorama==0.4.6 ; sys_platform == 'never' \\
    --hash=sha256:cc
Highs_Py==1.16.0 \\
    --hash=sha256:dd
    # via mambot-fleet (pyproject.toml)
"""


def test_pins_follow_this_interpreter_and_platform(tmp_path):
    lock = tmp_path / "requirements.lock"
    lock.write_text(LOCK)
    numpy = "2.4.6" if sys.version_info < (3, 12) else "2.5.5"
    assert check_lock.locked(lock) == {"numpy": numpy, "highs-py": "1.16.0"}


def test_every_difference_is_named():
    pins = {"numpy": "2.4.6", "simpy": "4.1.2", "shapely": "2.2.0"}
    have = {"numpy": "2.4.6", "simpy": "4.1.1", "uv": "0.13.9", "pip": "25.0"}
    assert check_lock.differences(pins, have) == [
        "shapely: locked 2.2.0, not installed",
        "simpy: locked 4.1.2, installed 4.1.1",
        "uv 0.13.9: installed, not in the lock",
    ]
    assert check_lock.differences(pins, {**have, "simpy": "4.1.2", "shapely": "2.2.0"}) == [
        "uv 0.13.9: installed, not in the lock"
    ]


def test_the_committed_lock_pins_every_direct_dependency():
    pins = check_lock.locked(REPO_ROOT / "requirements.lock")
    for name in (
        "simpy",
        "numpy",
        "pyomo",
        "highspy",
        "networkx",
        "pyzmq",
        "shapely",
        "rich",
        "matplotlib",
        "pytest",
        "hypothesis",
        "ruff",
        "distributed",
        "setuptools",
    ):
        assert name in pins, name
