"""docs/tutorial.md shows real things: its study is the shipped one and its plugin conforms."""

import re
import tomllib

import pytest

from fleet.plugins.testing import check_controller
from fleet.scenario import REPO_ROOT

TUTORIAL = (REPO_ROOT / "docs" / "tutorial.md").read_text(encoding="utf-8")


def blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", TUTORIAL, flags=re.S)


def test_the_tutorial_study_is_the_shipped_quick_study():
    shown = next(tomllib.loads(b) for b in blocks("toml") if "[study]" in b)
    shipped = tomllib.loads((REPO_ROOT / "studies" / "throughput_quick.toml").read_text())
    assert shown == shipped


def test_the_tutorial_controller_conforms_and_checks_its_option():
    source = next(b for b in blocks("python") if "class MarginQsp" in b)
    namespace: dict = {}
    exec(compile(source, "docs/tutorial.md", "exec"), namespace)
    margin_qsp = namespace["MarginQsp"]
    check_controller(margin_qsp, options={"margin": 0.8})
    with pytest.raises(ValueError, match="margin = 1.5"):
        margin_qsp(margin=1.5)
    toml = next(b for b in blocks("toml") if "fleet.controllers" in b)
    assert tomllib.loads(toml)["project"]["entry-points"]["fleet.controllers"] == {
        "margin_qsp": "margin_qsp.control:MarginQsp"
    }


def test_the_tutorial_pyproject_is_the_one_new_plugin_writes(tmp_path):
    # The tutorial's plugin did not install as written (no build-system table, no __init__.py):
    # now it shows what `fleet new-plugin` writes, which tests/test_new_plugin.py installs.
    from fleet.plugins.scaffold import write_plugin

    made = write_plugin("margin_qsp", "controller", tmp_path)
    shown = next(tomllib.loads(b) for b in blocks("toml") if "[build-system]" in b)
    assert shown == tomllib.loads((made.root / "pyproject.toml").read_text())
    assert (made.root / "src" / "margin_qsp" / "__init__.py").is_file()
    assert made.target == "margin_qsp.control:MarginQsp"
    assert "fleet new-plugin margin_qsp --kind controller" in TUTORIAL
