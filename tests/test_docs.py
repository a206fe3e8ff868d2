"""The shell commands of README.md and docs/*.md that are marked runnable run as written.

A fenced ``sh`` block right after an HTML comment ``<!-- runnable -->`` is runnable: the test
runs each of its commands (a line; a trailing backslash continues it) with bash, in order, in a
fresh folder per document that holds the repository's maps, scenarios, parts, studies and
scripts and its ``.venv``, so later blocks see what earlier ones wrote. Blocks marked
``<!-- runnable: slow -->`` take minutes and run only with ``FLEET_DOCS_SLOW=1``. Blocks
without a mark are left alone (``make``, a second machine, ``pip install`` into the project's
environment).
"""

import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from fleet.scenario import REPO_ROOT

DOCUMENTS = [REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").glob("*.md"))]
_BLOCK = re.compile(r"<!-- runnable(?P<slow>: slow)? -->\n```sh\n(?P<body>.*?)```", re.S)
#: What a fresh folder borrows from the repository, read-only.
SHARED = ("maps", "scenarios", "parts", "studies", "scripts")


@dataclass(frozen=True)
class Block:
    document: Path
    line: int
    slow: bool
    commands: tuple[str, ...]


def runnable_blocks(document: Path) -> list[Block]:
    text = document.read_text(encoding="utf-8")
    blocks = []
    for match in _BLOCK.finditer(text):
        commands: list[str] = []
        pending = ""
        for raw in match["body"].splitlines():
            line = pending + raw
            if line.endswith("\\"):
                pending = line[:-1] + " "
                continue
            pending = ""
            if line.strip() and not line.lstrip().startswith("#"):
                commands.append(line.strip())
        line_no = text.count("\n", 0, match.start()) + 1
        blocks.append(Block(document, line_no, bool(match["slow"]), tuple(commands)))
    return blocks


def fresh_folder(folder: Path) -> Path:
    for name in SHARED:
        (folder / name).symlink_to(REPO_ROOT / name, target_is_directory=True)
    (folder / ".venv").symlink_to(sys.prefix, target_is_directory=True)
    return folder


def run_blocks(blocks: list[Block], folder: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("FORCE_COLOR", "COLUMNS")}
    env["XDG_CONFIG_HOME"] = str(folder / "config")  # `fleet keys` writes there
    for block in blocks:
        for command in block.commands:
            proc = subprocess.run(
                ["bash", "-c", command],
                cwd=folder,
                env=env,
                capture_output=True,
                text=True,
                timeout=900,
            )
            where = f"{block.document.name}, block at line {block.line}: {command}"
            assert proc.returncode == 0, f"{where}\n{proc.stdout}\n{proc.stderr}"
            assert "Traceback" not in proc.stderr, f"{where}\n{proc.stderr}"


QUICK = [d for d in DOCUMENTS if any(not b.slow for b in runnable_blocks(d))]
SLOW = [d for d in DOCUMENTS if any(b.slow for b in runnable_blocks(d))]


@pytest.mark.parametrize("document", QUICK, ids=lambda p: p.name)
def test_runnable_commands_run_as_written(document, tmp_path):
    blocks = [b for b in runnable_blocks(document) if not b.slow]
    run_blocks(blocks, fresh_folder(tmp_path))


@pytest.mark.skipif(not os.environ.get("FLEET_DOCS_SLOW"), reason="set FLEET_DOCS_SLOW=1")
@pytest.mark.parametrize("document", SLOW, ids=lambda p: p.name)
def test_slow_runnable_commands_run_as_written(document, tmp_path):
    # Every block of the document, quick ones too: slow ones may read what quick ones wrote.
    run_blocks(runnable_blocks(document), fresh_folder(tmp_path))


def test_the_documents_mark_commands_runnable():
    assert {d.name for d in QUICK} >= {"README.md", "tutorial.md", "gcode.md"}


def test_the_readme_tour_is_runnable_and_includes_its_map_example():
    blocks = runnable_blocks(REPO_ROOT / "README.md")
    quick = [c for b in blocks if not b.slow for c in b.commands]
    # The tour's map example failed as written (that map has no depot_a); it runs now.
    assert any("--map maps/paper_case3.toml" in c for c in quick)
    assert any(c.startswith(".venv/bin/fleet keys") for c in quick)
    assert sum(len(b.commands) for b in blocks) >= 15


def test_a_failing_command_fails_the_run(tmp_path):
    block = Block(REPO_ROOT / "README.md", 1, False, (".venv/bin/fleet run --map nowhere.toml",))
    with pytest.raises(AssertionError, match="no such map file"):
        run_blocks([block], fresh_folder(tmp_path))
