"""The README's examples are tests (STYLE: examples are tests), read from README.md at test
time so that what is tested is what the README says:

- its first two shell commands are what CI runs (.ci/run reads them from the README);
- its Python block ("From Python") runs as written, and its arrays and figures are what its
  comments say;
- every `dynfab` command it lists is accepted by the command line's parser, with its
  placeholders (SCENE.toml, FILE.h5, DIR, ...) filled in;
- every such command is run by a test: the forms that another test file runs already (named
  in RUN_ELSEWHERE, which checks that file does run them) are not run twice; the others run
  here, in their quick form where they have one, writing to tmp_path.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from dynfab.cli import _parser, main
from dynfab.results.file import read_results
from dynfab.scene import load_scene, parse_scene_text
from independent import PAPER_WARP, PAPER_WEFT, scene_toml

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
CI_BLOCKS = 2
"""The first two shell blocks: CI's commands (.ci/run runs them)."""

TINY_SCENE = scene_toml({
    "geometry": {"length": 0.025, "segments": 16, "crossings": 4, "amplitude": 0.5e-3},
    "warp": PAPER_WARP, "weft": PAPER_WEFT,
    "load": {"control": "force", "values": [0.05]}})
"""What fills a SCENE placeholder: the paper's yarn cut to 4 crossings, N = 16, one force step."""

RUN_ELSEWHERE = {
    ("run", "static"): ("test_cli.py", ['"run"']),
    ("run", "dynamic"): ("test_cli_dynamic.py", ['"run"', '"--solver", "dynamic"']),
    ("run", "resume"): ("test_cli.py", ['"run"', '"--resume"']),
    ("plot",): ("test_cli.py", ['"plot"']),
    ("xdmf",): ("test_xdmf.py", ['"xdmf"']),
    ("fit",): ("test_fit_cli.py", ['"fit"']),
    ("fit", "runs/fit_example/scene.toml"): ("test_fit_cli.py", ['"fit"', '"scene.toml"',
                                                                 '"curve.csv"']),
    ("study",): ("test_study.py", ['"study"', '"--resume"']),
    ("study", "runs/study_example.toml"): ("test_study.py", ['"study"', '"study_example.toml"']),
    ("convergence", "quick"): ("test_convergence_report.py", ['"convergence"', '"--quick"']),
    ("precision", "quick"): ("test_precision_report.py", ['"precision"', '"--quick"']),
    ("stability", "quick"): ("test_stability_report.py", ['"stability"', '"--quick"']),
    ("figures", "quick"): ("test_figures_report.py", ['"figures"', '"--quick"']),
    ("fabric", "quick"): ("test_fabric_report.py", ['"fabric"', '"--quick"']),
}
"""A command's form (`form`) -> (the test file that runs it, the words its call holds)."""


def readme_commands() -> list[str]:
    """The shell code blocks of the README, in order."""
    return re.findall(r"```sh\n(.*?)\n```", README.read_text(), flags=re.S)


def python_block() -> str:
    """The Python block of the README's "From Python" section."""
    section = README.read_text().split("## From Python", 1)[1]
    return re.search(r"```python\n(.*?)\n```", section, flags=re.S).group(1)


def dynfab_commands(blocks: list[str]) -> list[str]:
    """Every `dynfab ...` command in the shell blocks, one a line or joined by &&, its
    comment dropped (a path before `dynfab`, as .venv/bin/dynfab, dropped too)."""
    commands = []
    for block in blocks:
        for line in block.splitlines():
            for part in line.split(" # ")[0].split("&&"):
                words = part.split()
                if words and Path(words[0]).name == "dynfab":
                    commands.append(" ".join(["dynfab", *words[1:]]))
    return commands


def filled(command: str, folder: Path) -> list[str]:
    """The command's arguments (after `dynfab`), placeholders filled with files in `folder`."""
    scene = folder / "scene.toml"
    if not scene.exists():
        scene.write_text(TINY_SCENE)
    values = {"SCENE.toml": scene, "[SCENE]": scene, "FILE.h5": folder / "file.h5",
              "DIR": folder / "dir", "CURVE.csv": folder / "curve.csv",
              "KEY[,KEY]": "warp.EA,warp.EI", "[--quick]": "--quick",
              "STUDY.toml": folder / "study.toml", "ADDRESS": "tcp://127.0.0.1:8786", "K": "3"}
    args = [str(values.get(word, word)) for word in shlex.split(command)[1:]]
    unknown = [word for word in args if re.fullmatch(r"\[?[A-Z][A-Z_,\[\]]*\]?(\.\w+)?", word)]
    assert not unknown, f"README command {command!r}: placeholders {unknown} unknown to this test"
    return args


def form(command: str) -> tuple:
    """What a command exercises: its subcommand, then the solver or --resume of a run, --quick
    of a report, and the scene file when the README names a real one."""
    words = shlex.split(command)[1:]
    sub, rest = words[0], words[1:]
    if sub == "run":
        mode = ("resume" if "--resume" in rest else
                rest[rest.index("--solver") + 1] if "--solver" in rest else "static")
        concrete = [w for w in rest if w.endswith(".toml") and w != "SCENE.toml"]
        return ("run", *concrete) if concrete else ("run", mode)
    concrete = [w for w in rest if w.endswith(".toml") and w not in ("SCENE.toml", "STUDY.toml")]
    if concrete:
        return (sub, *concrete)
    if "[SCENE]" in rest:
        return (sub, "scene", "quick")
    return (sub, "quick") if "[--quick]" in rest or "--quick" in rest else (sub,)


def listed_commands() -> list[str]:
    """The commands of the README outside CI's two blocks."""
    return dynfab_commands(readme_commands()[CI_BLOCKS:])


def commands_run_here() -> list[str]:
    """The listed commands whose form no other test runs."""
    return [c for c in listed_commands() if form(c) not in RUN_ELSEWHERE]


# --------------------------------------------------------------------------
# CI's commands.


def test_readme_opens_with_the_two_commands():
    text = README.read_text()
    first, second = readme_commands()[:CI_BLOCKS]
    assert text.index(first) < text.index("dynfab simulates")
    assert "dynfab run runs/paper_fig3.toml" in first and "dynfab plot" in first
    assert "pytest" in second


def test_ci_runs_both_readme_commands_from_the_readme():
    """.ci/run executes README blocks 0 and 1 as read from README.md (not a copy that could drift)."""
    ci = (ROOT / ".ci" / "run").read_text()
    assert 'README.md' in ci
    assert ci.index("readme_command 0") < ci.index("readme_command 1")


# --------------------------------------------------------------------------
# The Python block.


def test_the_python_block_runs_and_gives_what_its_comments_say(tmp_path, monkeypatch):
    # Run where it writes (fig5.h5, fig5_plots/), with the clone's runs/ beside it.
    (tmp_path / "runs").symlink_to(ROOT / "runs")
    monkeypatch.chdir(tmp_path)
    code = python_block()
    names: dict = {}
    exec(compile(code, "README.md (From Python)", "exec"), names)
    scene = names["scene"]
    steps, yarns = len(scene.load.values), len(scene.sweep[0][1]) if scene.sweep else 1
    assert names["force"].shape == names["stretch"].shape == (steps, yarns)  # (steps, yarns)
    assert np.array_equal(names["same"].steps["end_force"], names["force"])  # the same arrays
    figures = re.findall(r"(\w+\.png)", code)
    assert figures, "the block names the figures it draws"
    for figure in figures:
        assert (tmp_path / "fig5_plots" / figure).stat().st_size > 0


# --------------------------------------------------------------------------
# The command list.


def test_the_readme_lists_commands():
    assert len(listed_commands()) >= 5  # the "Command line" block at least


@pytest.mark.parametrize("command", dynfab_commands(readme_commands()))
def test_every_readme_command_is_accepted_by_the_parser(command, tmp_path):
    try:
        _parser().parse_args(filled(command, tmp_path))
    except SystemExit as error:
        pytest.fail(f"README command {command!r}: the parser refuses it (status {error.code})")


def test_every_readme_command_is_run_by_a_test():
    # A form listed in RUN_ELSEWHERE is run by that file (its call holds the words); the
    # others are run by test_the_commands_no_other_test_runs below.
    for command in listed_commands():
        if form(command) in RUN_ELSEWHERE:
            name, words = RUN_ELSEWHERE[form(command)]
            text = (ROOT / "tests" / name).read_text()
            for word in words:
                assert word in text, f"{command!r}: {name} was to run it, and has no {word}"


@pytest.mark.parametrize("command", commands_run_here())
def test_the_commands_no_other_test_runs(command, tmp_path, monkeypatch, capsys):
    # From a folder holding the clone's runs/, so that the README's relative paths hold and
    # what the command writes lands in tmp_path.
    (tmp_path / "runs").symlink_to(ROOT / "runs")
    monkeypatch.chdir(tmp_path)
    args = filled(command, tmp_path)
    main([*args, "--quiet"] if "--quiet" not in args else args)
    sub = args[0]
    if sub == "run":
        out = Path(args[args.index("--out") + 1])
        scene = load_scene(args[1])
        results = read_results(out)
        assert results.step_count == len(scene.load.values)
        assert parse_scene_text(results.attrs["scene"]).load == scene.load
    else:
        out = Path(args[args.index("--out") + 1])
        assert any(out.iterdir()), f"{command!r} wrote nothing to {out}"
    assert "Traceback" not in capsys.readouterr().err


def test_the_readme_names_the_python_it_needs_as_pyproject_does():
    # a newcomer reads which Python the commands need, and it is the package's own floor
    import tomllib

    needed = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["requires-python"]
    version = needed.removeprefix(">=")
    text = README.read_text()
    assert f"Python {version} or newer" in text and "`requires-python`" in text
    assert "warnings summary" in text  # and what its expected warnings are


def test_a_benchmark_flag_the_readme_names_is_said_to_be_the_benchmarks():
    # `--friction-beta` belongs to benchmarks/shear.py, not to `dynfab run`: where the README
    # names it, it says so
    text = README.read_text()
    at = text.index("--friction-beta")
    assert "benchmarks/shear.py" in text[at:at + 120]
    assert "--friction-beta" not in {a for action in _parser()._actions
                                     for a in getattr(action, "option_strings", [])}
