"""Every `fleet` command, fed junk, answers with a one-paragraph error and its documented exit
status: never a traceback, and never the catch-all "unexpected" message that marks a bug.

Junk is what a new user hands over by mistake: a file of random bytes, a text file that is not
what the command reads (the README), an empty file, a directory, a path that does not exist,
and option values of the wrong form. Exit status (fleet/cli.py): 1 bad input, 2 usage.
"""

import random
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fleet.cli import EXIT_FAILED, EXIT_USAGE, main
from fleet.scenario import REPO_ROOT

KINDS = ("random_bytes", "text", "empty", "directory", "missing")

#: Commands that read one file or directory, with the arguments they need besides it.
FILE_COMMANDS = {
    "run": ["run", "{}", "--quiet", "--no-figures", "--out", "{out}"],
    "run --map": ["run", "--map", "{}", "--quiet", "--no-figures", "--out", "{out}"],
    "run --set scenario.map": ["run", "--set", "scenario.map={}", "--quiet", "--out", "{out}"],
    "serve": ["serve", "{}", "--bind", "ipc://{out}/engine", "--wait", "1", "--out", "{out}"],
    "agent": ["agent", "{}", "--connect", "tcp://127.0.0.1:9", "--wait", "1"],
    "sweep": ["sweep", "{}", "--out", "{out}", "--quiet"],
    "report": ["report", "{}", "--out", "{out}"],
    "plot": ["plot", "{}"],
    "replay": ["replay", "{}", "--out", "{out}/replay.html"],
    "map": ["map", "{}"],
    "gcode": ["gcode", "{}"],
    "keys": ["keys", "{}"],
}
#: Run and study directories hold files: the same junk, inside an otherwise proper folder.
DIRECTORY_FILES = {
    "report": ("results.csv", "study.json"),
    "plot": ("trajectories.csv", "summary.json"),
    "replay": ("trajectories.csv", "summary.json"),
}
#: What each command accepts among the junk kinds (keys makes a missing folder, as it should).
ACCEPTED = {("keys", "directory"), ("keys", "missing")}


def junk(kind: str, folder: Path) -> Path:
    path = folder / f"junk_{kind}"
    if kind == "random_bytes":
        path.write_bytes(random.Random(19).randbytes(4096))
    elif kind == "text":
        shutil.copy(REPO_ROOT / "README.md", path)
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "directory":
        path.mkdir()
    return path


def call(argv: list[str], capsys) -> tuple[int, str, str]:
    status = main(argv)
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def assert_refused(status: int, err: str, expected: int, names: str) -> None:
    assert status == expected, err
    assert "Traceback" not in err
    assert "unexpected" not in err, err  # the catch-all for bugs: a parser let junk through
    if expected == EXIT_FAILED:
        assert err.startswith("error: "), err
        assert names in err, err
    else:
        assert "usage: fleet" in err and "error:" in err, err


@pytest.fixture(autouse=True)
def outside_the_repository(tmp_path, monkeypatch):
    """Run from a scratch folder (nothing lands in the work tree), keys in a scratch home."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("command", sorted(FILE_COMMANDS))
def test_every_command_refuses_junk_files_naming_them(command, kind, tmp_path, capsys):
    path = junk(kind, tmp_path)
    out = tmp_path / "out"
    argv = [a.format(path, out=out) for a in FILE_COMMANDS[command]]
    status, _, err = call(argv, capsys)
    if (command, kind) in ACCEPTED:
        assert status == 0, err
        return
    assert_refused(status, err, EXIT_FAILED, str(path))


@pytest.mark.parametrize("kind", ["random_bytes", "text", "empty"])
@pytest.mark.parametrize("command", sorted(DIRECTORY_FILES))
def test_junk_inside_a_run_or_study_directory_is_named(command, kind, tmp_path, capsys):
    folder = tmp_path / "dir"
    folder.mkdir()
    source = junk(kind, tmp_path)
    for name in DIRECTORY_FILES[command]:
        shutil.copy(source, folder / name)
    argv = [a.format(folder, out=tmp_path / "out") for a in FILE_COMMANDS[command]]
    status, _, err = call(argv, capsys)
    assert_refused(status, err, EXIT_FAILED, str(folder))


BAD_OPTIONS = [
    # (argv, exit status, what the message must name)
    (["run", "--robots", "many"], EXIT_USAGE, "--robots"),
    (["run", "--robots", "0"], EXIT_USAGE, "--robots"),
    (["run", "--duration", "-5"], EXIT_USAGE, "--duration"),
    (["run", "--seed", "x"], EXIT_USAGE, "--seed"),
    (["run", "--workers", "-1"], EXIT_USAGE, "--workers"),
    (["run", "--set", "robots.count"], EXIT_USAGE, "--set"),
    (["run", "--set", "=8"], EXIT_USAGE, "--set"),
    (["run", "--set", "robots.count=many"], EXIT_FAILED, "robots.count = 'many'"),
    (["run", "--set", "robots.cuont=8"], EXIT_FAILED, "robots.cuont = 8: unknown key"),
    (["run", "--set", "robots.count.x=1"], EXIT_FAILED, "robots.count.x = 1"),
    (["run", "--latency", "fast"], EXIT_FAILED, "--latency = 'fast'"),
    (["run", "--map", "nowhere.toml"], EXIT_FAILED, "--map = 'nowhere.toml'"),
    (["run", "--controller", "nobody"], EXIT_FAILED, "'nobody'"),
    (["run", "--dispatcher", "nobody"], EXIT_FAILED, "'nobody'"),
    (["run", "--bogus"], EXIT_USAGE, "--bogus"),
    (["serve", "--bind", "localhost:5555"], EXIT_USAGE, "--bind"),
    (["serve", "--bind", "ipc:///tmp/x", "--wait", "0"], EXIT_USAGE, "--wait"),
    (["serve", "--bind", "ipc:///tmp/x", "--key", "k"], EXIT_FAILED, "--authorized"),
    (["agent", "--connect", "HOST:5555"], EXIT_USAGE, "--connect"),
    (["agent", "--connect", "tcp://127.0.0.1:9", "--share", "3/2"], EXIT_FAILED, "3/2"),
    (["agent", "--connect", "tcp://127.0.0.1:9", "--only", "r99"], EXIT_FAILED, "r99"),
    (["agent", "--connect", "tcp://127.0.0.1:9", "--key", "k"], EXIT_FAILED, "--server-key"),
    (["keys", "--name", "../escape"], EXIT_FAILED, "'../escape'"),
    (["sweep"], EXIT_USAGE, "study"),
    (["sweep", "s.toml", "--jobs", "zero"], EXIT_USAGE, "--jobs"),
    (["report"], EXIT_USAGE, "study_dir"),
    (["plot", "a", "b"], EXIT_USAGE, "unrecognized arguments"),
    (["plugins", "--all"], EXIT_USAGE, "--all"),
    (["new-plugin", "Bad-Name", "--kind", "controller"], EXIT_FAILED, "'Bad-Name'"),
    (["new-plugin", "fine", "--kind", "planner"], EXIT_USAGE, "--kind"),
    (["new-plugin", "fine"], EXIT_USAGE, "--kind"),
    (["map"], EXIT_USAGE, "file"),
    (["gcode", "part.gcode", "--min-task", "soon"], EXIT_USAGE, "--min-task"),
    (["schema", "robot"], EXIT_USAGE, "'robot'"),
    (["nosuchcommand"], EXIT_USAGE, "'nosuchcommand'"),
    ([], EXIT_USAGE, "COMMAND"),
]


@pytest.mark.parametrize(
    ("argv", "status", "names"), BAD_OPTIONS, ids=[" ".join(a[0]) or "nothing" for a in BAD_OPTIONS]
)
def test_bad_options_are_refused_naming_the_option_and_value(argv, status, names, capsys):
    got, out, err = call(argv, capsys)
    assert_refused(got, err, status, names)
    if status == EXIT_USAGE:
        assert names in err, err


def test_gcode_classify_and_schema_out_name_the_bad_value(tmp_path, capsys):
    prism = str(REPO_ROOT / "parts" / "prism_40x20x2.gcode")
    status, _, err = call(["gcode", prism, "--classify", "Skirt=glitter"], capsys)
    assert_refused(status, err, EXIT_FAILED, "'glitter'")
    status, _, err = call(["schema", "map", "--out", str(tmp_path)], capsys)
    assert_refused(status, err, EXIT_FAILED, f"--out = '{tmp_path}'")
    status, _, err = call(["new-plugin", "fine", "--kind", "controller", "--out", prism], capsys)
    assert_refused(status, err, EXIT_FAILED, prism)


def test_debug_shows_the_traceback_with_the_same_status(tmp_path, capsys):
    path = junk("random_bytes", tmp_path)
    status, _, err = call(["map", str(path)], capsys)
    assert status == EXIT_FAILED and "Traceback" not in err
    for argv in (["--debug", "map", str(path)], ["map", str(path), "--debug"]):
        status, _, err = call(argv, capsys)
        assert status == EXIT_FAILED
        assert "Traceback (most recent call last)" in err and "MapError" in err
        assert err.rstrip().splitlines()[-1].startswith("error: ")


def test_a_bug_is_reported_as_one_and_debug_raises_it(monkeypatch, capsys):
    import fleet.cli

    def broken(*args):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(fleet.cli, "_cmd_plugins", broken)
    monkeypatch.setattr(fleet.cli, "_parser", _parser_with(fleet.cli._parser, broken))
    status, _, err = call(["plugins"], capsys)
    assert status == EXIT_FAILED
    assert "unexpected ZeroDivisionError: division by zero" in err and "--debug" in err
    assert "Traceback" not in err
    with pytest.raises(ZeroDivisionError):
        main(["--debug", "plugins"])


def _parser_with(make, handler):
    def parser():
        p = make()
        p._subparsers._group_actions[0].choices["plugins"].set_defaults(handler=handler)
        return p

    return parser


def test_the_console_script_prints_no_traceback_on_junk(tmp_path):
    exe = shutil.which("fleet", path=str(Path(sys.executable).parent))
    assert exe, "the console script `fleet` is installed next to the interpreter"
    readme = REPO_ROOT / "README.md"
    proc = subprocess.run(
        [exe, "gcode", str(readme)], capture_output=True, text=True, timeout=60, cwd=tmp_path
    )
    assert proc.returncode == EXIT_FAILED
    assert proc.stdout == "" and "Traceback" not in proc.stderr
    assert proc.stderr.startswith(f"error: {readme}: line 1 = '# mambot-fleet': not G-code")
