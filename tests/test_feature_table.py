"""The README's feature table ("What runs on which model"): every feature against every model,
no empty cell, each `yes` backed by a test that exists, each `no` with its reason.

Read from README.md at test time, so that what is checked is what the README says: the
columns are the three models; every cell starts with `yes` or `no`; a `yes` cell names at
least one `tests/FILE.py::test_name` whose file exists and defines a function `test_name`
(found with ast, so a name in a comment or a string does not count); a `no` cell gives a
reason of a few words.
"""

from __future__ import annotations

import ast
import re
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
SECTION = "## What runs on which model"
COLUMNS = ["feature", "one yarn (paper)", "fabric: clamped patch", "fabric: periodic cell",
           "shear specimen (spatial)"]
REFERENCE = re.compile(r"`(tests/[\w/]+\.py)::(\w+)(?:\[([\w.-]+)\])?`")
"""A test named in a cell: `tests/FILE.py::test_name`, or one case of a parametrised test,
`tests/FILE.py::test_name[case]`."""
REASON_WORDS = 4
"""The fewest words a `no` cell's reason has."""


def split_row(line: str) -> list[str]:
    """The cells of a markdown table row, stripped ('| a | b |' -> ['a', 'b'])."""
    return [cell.strip() for cell in line.strip().strip("|").split("|")]


def feature_table(text: str) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of the table in the README's SECTION (the first table after its
    heading, before the next section)."""
    assert SECTION in text, f"README.md has no section {SECTION!r}"
    section = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    lines = [line for line in section.splitlines() if line.lstrip().startswith("|")]
    assert len(lines) >= 3, "the section holds no table"
    header, rule, *rows = lines
    assert set(rule.replace("|", "").split()) <= {"---", ":---", "---:", ":---:"}, rule
    return split_row(header), [split_row(row) for row in rows]


@cache
def defined_tests(path: Path) -> frozenset[str]:
    """The names of the functions a test file defines at its top level."""
    tree = ast.parse(path.read_text(), filename=str(path))
    return frozenset(node.name for node in tree.body
                     if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)))


def cell_problems(cell: str) -> list[str]:
    """What is wrong with one model's cell (empty list: nothing)."""
    if not cell:
        return ["an empty cell"]
    word = re.match(r"(yes|no)\b", cell)
    if word is None:
        return [f"starts with neither yes nor no: {cell!r}"]
    if word.group(1) == "no":
        reason = cell[2:].lstrip(" :-—,")
        return [] if len(reason.split()) >= REASON_WORDS else [f"a no without a reason: {cell!r}"]
    references = REFERENCE.findall(cell)
    if not references:
        return [f"a yes naming no `tests/FILE.py::test_name`: {cell!r}"]
    problems = []
    for file, name, case in references:
        path = ROOT / file
        if not path.is_file():
            problems.append(f"{file} does not exist")
        elif name not in defined_tests(path):
            problems.append(f"{file} defines no function {name}")
        elif case and f'"{case}"' not in path.read_text():
            problems.append(f"{file} names no case {case!r} (its id, quoted, in the source)")
    return problems


def table_problems(text: str) -> list[str]:
    """Every problem of the README text's feature table, as 'feature / model: problem'."""
    header, rows = feature_table(text)
    if header != COLUMNS:
        return [f"the columns are {header}, not {COLUMNS}"]
    problems = []
    for row in rows:
        if len(row) != len(COLUMNS):
            problems.append(f"{row[0]!r}: {len(row)} cells, not {len(COLUMNS)}")
            continue
        if not row[0]:
            problems.append("a row without its feature")
        for model, cell in zip(COLUMNS[1:], row[1:]):
            problems += [f"{row[0]} / {model}: {p}" for p in cell_problems(cell)]
    return problems


FEATURES = ("static solver", "friction onset", "dynamic explicit", "dynamic semi-implicit",
            "node-parallel layout", "transient", "float32", "physical masses", "`[sweep]`",
            "memory and disk refusal", "`--resume`", "XDMF", "`dynfab plot`", "`dynfab fit`",
            "`dynfab study`", "Ctrl-C")
"""How each feature the table must hold begins its row."""


def test_the_readme_table_is_full_and_every_yes_names_an_existing_test():
    assert table_problems(README.read_text()) == []


def test_the_table_has_a_row_for_every_feature():
    _, rows = feature_table(README.read_text())
    features = [row[0] for row in rows]
    for feature in FEATURES:
        assert any(f.startswith(feature) for f in features), feature


def readme_with(edit) -> str:
    """The README with its table's first data row's cells passed through `edit` (a function
    of the list of cells returning the new list)."""
    text = README.read_text()
    header, rows = feature_table(text)
    first = next(line for line in text.split(SECTION, 1)[1].splitlines()
                 if line.startswith("|") and split_row(line) == rows[0])
    return text.replace(first, "| " + " | ".join(edit(list(rows[0]))) + " |", 1)


BROKEN = {
    "empty cell": (lambda row: row[:2] + [""] + row[3:], "an empty cell"),
    "missing test": (lambda row: row[:1] + ["yes: `tests/test_static.py::test_not_there`"]
                     + row[2:], "defines no function test_not_there"),
    "missing file": (lambda row: row[:1] + ["yes: `tests/test_not_there.py::test_x`"] + row[2:],
                     "tests/test_not_there.py does not exist"),
    "missing case": (lambda row: row[:1]
                     + ["yes: `tests/test_shear_dynamic.py::test_dynamic_positions_agree_with"
                        "_static_within_the_error_bounds[frame-not-there]`"] + row[2:],
                     "names no case 'frame-not-there'"),
    "yes without a test": (lambda row: row[:1] + ["yes"] + row[2:], "a yes naming no"),
    "no without a reason": (lambda row: row[:1] + ["no"] + row[2:], "a no without a reason"),
    "neither": (lambda row: row[:1] + ["maybe: later"] + row[2:], "neither yes nor no"),
    "a column less": (lambda row: row[:3], "cells, not 5"),
}
"""Edits of the table that its check must catch -> (edit, a piece of the problem it names)."""


@pytest.mark.parametrize("name", sorted(BROKEN))
def test_a_broken_table_is_caught(name):
    edit, message = BROKEN[name]
    problems = table_problems(readme_with(edit))
    assert any(message in p for p in problems), problems


def test_other_columns_are_caught():
    text = README.read_text().replace("| fabric: periodic cell |", "| fabric: cell |", 1)
    renamed = COLUMNS[:3] + ["fabric: cell"] + COLUMNS[4:]
    assert table_problems(text) == [f"the columns are {renamed}, not {COLUMNS}"]
