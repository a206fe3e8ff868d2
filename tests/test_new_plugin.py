"""`fleet new-plugin` writes a package that installs, is discovered and passes the conformance
kit exactly as generated.

The package is installed for real (``pip install -e``) into a throw-away virtual environment
that sees this one's packages, so the project's own environment never holds it.
"""

import subprocess
import sys
import sysconfig
import tomllib
import venv
from pathlib import Path

import pytest

from fleet.cli import EXIT_FAILED, main
from fleet.plugins.scaffold import KINDS


def scratch_venv(folder: Path) -> Path:
    """A venv without pip whose interpreter also imports everything this one does."""
    venv.EnvBuilder(with_pip=False).create(folder)
    python = folder / "bin" / "python"
    purelib = subprocess.run(
        [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    # addsitedir, not a bare path: this environment's own .pth files (the editable install of
    # mambot-fleet among them) must be read too.
    ours = sysconfig.get_paths()["purelib"]
    (Path(purelib) / "_outer_env.pth").write_text(f"import site; site.addsitedir({ours!r})\n")
    return python


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_a_new_plugin_installs_is_found_and_passes_the_kit(kind, tmp_path, capsys):
    name = f"my_{kind}"
    assert main(["new-plugin", name, "--kind", kind, "--out", str(tmp_path)]) == 0
    root = tmp_path / name
    printed = capsys.readouterr().out
    assert f"next: pip install -e {root}" in " ".join(printed.split())

    project = tomllib.loads((root / "pyproject.toml").read_text())
    assert project["build-system"]["build-backend"] == "setuptools.build_meta"
    target = {
        "controller": "control:MyController",
        "dispatcher": "dispatch:MyDispatcher",
        "charging": "policy:MyCharging",
    }[kind]
    assert project["project"]["entry-points"][KINDS[kind]] == {name: f"{name}.{target}"}
    assert (root / "src" / name / "__init__.py").is_file()

    python = scratch_venv(tmp_path / "venv")
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--python", str(python)]
    install = subprocess.run(
        [*pip, "install", "--quiet", "--no-deps", "--no-build-isolation", "-e", str(root)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert install.returncode == 0, install.stderr

    listed = subprocess.run(
        [python, "-m", "fleet", "plugins"], capture_output=True, text=True, timeout=120
    )
    assert listed.returncode == 0, listed.stderr
    row = next(line for line in listed.stdout.splitlines() if f" {name} " in line)
    assert kind in row and "ok" in row

    tests = subprocess.run(
        [python, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(root / "tests")],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=root,
    )
    assert tests.returncode == 0, tests.stdout + tests.stderr
    assert "2 passed" in tests.stdout


def test_new_plugin_never_overwrites(tmp_path, capsys):
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "keep.txt").write_text("mine")
    argv = ["new-plugin", "taken", "--kind", "controller", "--out", str(tmp_path)]
    assert main(argv) == EXIT_FAILED
    assert "already exists and is not empty" in capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "taken").iterdir()) == ["keep.txt"]
