"""The README's first commands are what CI runs and what a user types (STYLE: examples are tests)."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    """The shell code blocks of the README, in order."""
    return re.findall(r"```sh\n(.*?)\n```", (ROOT / "README.md").read_text(), flags=re.S)


def test_readme_opens_with_the_two_commands():
    text = (ROOT / "README.md").read_text()
    first, second = readme_commands()[:2]
    assert text.index(first) < text.index("dynfab simulates")
    assert "dynfab run runs/paper_fig3.toml" in first and "dynfab plot" in first
    assert "pytest" in second


def test_ci_runs_both_readme_commands_from_the_readme():
    """.ci/run executes README blocks 0 and 1 as read from README.md (not a copy that could drift)."""
    ci = (ROOT / ".ci" / "run").read_text()
    assert 'README.md' in ci
    assert ci.index("readme_command 0") < ci.index("readme_command 1")
