"""The README's plugin example is real code: it runs, and it passes the conformance kit."""

import re

from fleet.plugins.testing import check_controller, check_dispatcher
from fleet.scenario import REPO_ROOT


def readme_blocks(language: str) -> list[str]:
    text = (REPO_ROOT / "README.md").read_text(encoding="utf-8")
    return re.findall(rf"```{language}\n(.*?)```", text, flags=re.S)


def test_plugin_example_passes_conformance():
    example = next(b for b in readme_blocks("python") if "class Replay(Controller)" in b)
    namespace: dict = {}
    exec(compile(example, "README.md", "exec"), namespace)
    check_controller(namespace["Replay"])
    check_dispatcher(namespace["OldestFirst"])
    # The test snippet in the README calls the kit on exactly these names.
    check_snippet = next(b for b in readme_blocks("python") if "def test_conformance" in b)
    assert "check_controller(Replay)" in check_snippet
    assert "check_dispatcher(OldestFirst)" in check_snippet


def test_entry_point_example_names_the_example_classes():
    toml = next(b for b in readme_blocks("toml") if "fleet.controllers" in b)
    assert 'replay = "my_fleet_plugins.basic:Replay"' in toml
    assert 'oldest_first = "my_fleet_plugins.basic:OldestFirst"' in toml
