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
    source = next(b for b in blocks("python") if "class MarginQSP" in b)
    namespace: dict = {}
    exec(compile(source, "docs/tutorial.md", "exec"), namespace)
    margin_qsp = namespace["MarginQSP"]
    check_controller(margin_qsp, options={"margin": 0.8})
    with pytest.raises(ValueError, match="margin = 1.5"):
        margin_qsp(margin=1.5)
    toml = next(b for b in blocks("toml") if "fleet.controllers" in b)
    assert tomllib.loads(toml)["project"]["entry-points"]["fleet.controllers"] == {
        "margin_qsp": "my_plugins.margin:MarginQSP"
    }
