"""Check that this environment holds exactly the lock's versions: each package the lock lists
for this platform and Python installed at its locked version, and nothing else installed but
pip and the project itself.

`make` runs it after installing from the lock (`pip check` only says the versions agree with
each other, not with the lock). Exit status 1, with one line per difference, when they differ.

    python scripts/check_lock.py [requirements.lock]
"""

from __future__ import annotations

import importlib.metadata
import re
import sys
from pathlib import Path

from packaging.markers import Marker
from packaging.utils import canonicalize_name

#: Installed besides the lock's packages: the installer and the project itself.
ALLOWED = {"pip", "mambot-fleet"}

_PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s;\\]+)\s*(?:;\s*([^\\]+?))?\s*\\?$")


def locked(lock: Path) -> dict[str, str]:
    """The lock's pins that apply to this interpreter and platform: name -> version."""
    pins: dict[str, str] = {}
    for line in lock.read_text(encoding="utf-8").splitlines():
        match = _PIN.match(line)
        if match is None:
            continue
        name, version, marker = match.groups()
        if marker is None or Marker(marker).evaluate():
            pins[canonicalize_name(name)] = version
    return pins


def installed() -> dict[str, str]:
    """Every distribution in this environment: name -> version."""
    return {
        canonicalize_name(d.metadata["Name"]): d.version for d in importlib.metadata.distributions()
    }


def differences(pins: dict[str, str], have: dict[str, str]) -> list[str]:
    problems = []
    for name, version in sorted(pins.items()):
        if name not in have:
            problems.append(f"{name}: locked {version}, not installed")
        elif have[name] != version:
            problems.append(f"{name}: locked {version}, installed {have[name]}")
    for name in sorted(set(have) - set(pins) - ALLOWED):
        problems.append(f"{name} {have[name]}: installed, not in the lock")
    return problems


def main(argv: list[str]) -> int:
    lock = Path(argv[0]) if argv else Path(__file__).resolve().parent.parent / "requirements.lock"
    pins = locked(lock)
    problems = differences(pins, installed())
    for line in problems:
        print(f"{lock}: {line}", file=sys.stderr)
    if not problems:
        print(f"{lock}: all {len(pins)} locked packages installed at their versions, nothing else")
    return 1 if problems else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
