"""Branches on the kind of model in dynfab/ and kernels/, outside the builders and the element
library.

Run:  python benchmarks/model_kind_branches.py                              (the working tree)
      python benchmarks/model_kind_branches.py --rev a2b9d22 --rev HEAD --list
                                                                            (two commits, each site)

A branch: the test of an `if`/`elif`, a conditional expression or a comprehension's `if`,
or a `wp.static(...)` call in none of these (found with `ast`). It branches on the kind of
model (one count a site) when its test has
- [class] `isinstance(x, ...Model)`, or `hasattr`/`getattr` of a model (`model`, `self.model`);
- [kind] a string "yarn", "fabric" or "specimen" (not compared with a `table`, `key` or `name`),
  "...weft_positions", a `.model` attribute compared (`scene.geometry.model == ...`), a
  `.specimen`, `.weft`, `.fabric` or `.model` attribute or a `specimen` or `fabric` name taken
  as true or compared with None (`scene.specimen is None`), `model.kind`, `is_fabric`,
  `is_specimen` or `has_weft`;
- [kinematics] a string "planar" or "spatial", a name or attribute `spatial`, `is_spatial`,
  `planar`, `planar_only` or `kinematics`, or the dimension (`dim`, `d`, `x.dim`, `dim(x)`,
  `x.shape[1]`) compared with 2 or 3;
- or calls a function of its file whose one statement returns a comparison or boolean
  operation meeting these rules (`scene._sets_layout`).
Not counted: a key's, dtype's or Jacobian's `kind`, the control, the boundary ("periodic"),
a kernel variant's terms (`wp.static(boundary)`, `has_friction`). Left out: the builders
(dynfab/builders/, dynfab/model/builders/), the element library (dynfab/terms/,
dynfab/model/terms/, kernels/spatial_terms.py). Files as in benchmarks/code_lines.py. Prints
the count per file and in total per revision (--list: each site, file:line: [rule] test);
writes benchmarks/model_kind_branches.json.
"""

from __future__ import annotations

import argparse
import ast
import json
from collections import Counter

from code_lines import ROOT, WORKTREE, git, python_files, read

LEFT_OUT = ("dynfab/builders/", "dynfab/model/builders/", "dynfab/terms/",
            "dynfab/model/terms/", "kernels/spatial_terms.py")
WORDS = {"yarn": "kind", "fabric": "kind", "specimen": "kind",
         "planar": "kinematics", "spatial": "kinematics"}
NAMES = {"is_fabric": "kind", "is_specimen": "kind", "has_weft": "kind", "spatial": "kinematics",
         "is_spatial": "kinematics", "planar": "kinematics", "planar_only": "kinematics",
         "kinematics": "kinematics"}
PRESENT_ATTRIBUTES = {"specimen", "weft", "fabric", "model"}
PRESENT_NAMES = {"specimen", "fabric"}  # not `weft`: a flag of a weft load
NOT_MODEL = {"table", "key", "name"}  # a scene table's or key's name compared with a string


def name(node: ast.AST) -> str:
    """The identifier of a Name, an Attribute's attribute or a called function; else ""."""
    node = node.func if isinstance(node, ast.Call) else node
    return node.id if isinstance(node, ast.Name) else getattr(node, "attr", "")


def is_dimension(node: ast.AST) -> bool:
    """`dim`, `d`, `x.dim`, `dim(x)` or `x.shape[1]`."""
    if isinstance(node, ast.Subscript):
        return name(node.value) == "shape" and ast.unparse(node.slice) == "1"
    return node.id in ("dim", "d") if isinstance(node, ast.Name) else name(node) == "dim"


def call_rule(node: ast.Call, predicates: dict[str, str]) -> str | None:
    """isinstance of a Model, hasattr/getattr of a model, or a predicate of the kind."""
    if name(node) == "isinstance" and len(node.args) == 2:
        return "class" if any(name(n).endswith("Model") for n in ast.walk(node.args[1])) else None
    if name(node) in ("hasattr", "getattr") and node.args:
        return "class" if name(node.args[0]).endswith("model") else None
    return predicates.get(name(node))


def compare_rule(node: ast.Compare) -> str | None:
    """The dimension compared with 2 or 3, or a `.model` attribute compared."""
    sides = (node.left, *node.comparators)
    if any(isinstance(s, ast.Constant) and s.value in (2, 3) for s in sides) and any(
            is_dimension(s) for s in sides) and isinstance(node.ops[0], ast.Eq | ast.NotEq):
        return "kinematics"
    return "kind" if any(isinstance(s, ast.Attribute) and s.attr == "model"
                         for s in sides) else None


def node_rule(node: ast.AST, predicates: dict[str, str]) -> str | None:
    """The rule one node of a test meets, or None."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return WORDS.get(node.value) or ("kind" if node.value.endswith("weft_positions") else None)
    if isinstance(node, ast.Call):
        return call_rule(node, predicates)
    if isinstance(node, ast.Compare):
        return compare_rule(node)
    if (isinstance(node, ast.Attribute) and node.attr == "kind"
            and name(node.value).endswith("model")):
        return "kind"
    return NAMES.get(name(node)) if isinstance(node, ast.Name | ast.Attribute) else None


def taken_as_true(test: ast.expr) -> list[ast.expr]:
    """The parts of `test` taken as true or false, or compared with None."""
    found = [test]
    for node in ast.walk(test):
        if isinstance(node, ast.BoolOp):
            found += node.values
        elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
            found.append(node.operand)
        elif isinstance(node, ast.Compare) and any(
                isinstance(c, ast.Constant) and c.value is None for c in node.comparators):
            found.append(node.left)
    return found


def rule(test: ast.expr, predicates: dict[str, str]) -> str | None:
    """The first rule that `test` meets, or None: not a branch on the kind of model."""
    skipped = {id(c) for n in ast.walk(test) if isinstance(n, ast.Compare)
               and name(n.left) in NOT_MODEL for c in n.comparators}
    for node in ast.walk(test):
        if id(node) not in skipped and (found := node_rule(node, predicates)):
            return found
    present = any(isinstance(n, ast.Attribute) and n.attr in PRESENT_ATTRIBUTES
                  or isinstance(n, ast.Name) and n.id in PRESENT_NAMES for n in taken_as_true(test))
    return "kind" if present else None


def predicates_of(tree: ast.AST) -> dict[str, str]:
    """The file's functions whose one statement returns a comparison or boolean operation
    that meets a rule (`_sets_layout`), and that rule."""
    found = {}
    for node in (n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)):
        body = node.body[1:] if ast.get_docstring(node) is not None else node.body
        value = body[0].value if len(body) == 1 and isinstance(body[0], ast.Return) else None
        if isinstance(value, ast.Compare | ast.BoolOp | ast.UnaryOp) and (kind := rule(value, {})):
            found[node.name] = kind
    return found


def tests(tree: ast.AST) -> list[ast.expr]:
    """The tests of the ifs, conditional expressions and comprehension ifs, then the
    `wp.static(...)` calls in none of them."""
    found = []
    for node in ast.walk(tree):
        found += [node.test] if isinstance(node, ast.If | ast.IfExp) else getattr(node, "ifs", [])
    inside = {id(n) for test in found for n in ast.walk(test)}
    return found + [n for n in ast.walk(tree) if isinstance(n, ast.Call)
                    and ast.unparse(n.func) == "wp.static" and id(n) not in inside]


def sites(rev: str) -> list[dict]:
    """Each branch on the kind of model at `rev`: file, line, rule and the test's source."""
    found = []
    for path in (p for p in python_files(rev) if not p.startswith(LEFT_OUT)):
        tree = ast.parse(read(rev, path))
        predicates = predicates_of(tree)
        found += [{"file": path, "line": test.lineno, "rule": kind, "test": ast.unparse(test)}
                  for test in tests(tree) if (kind := rule(test, predicates))]
    return sorted(found, key=lambda s: (s["file"], s["line"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rev", action="append", help="a git revision (repeatable; default: "
                        "the working tree)")
    parser.add_argument("--list", action="store_true", help="print each site")
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args()
    record = {"revisions": {}, "counts": {}, "totals": {}, "sites": {}}
    for rev in args.rev or [WORKTREE]:
        found = record["sites"][rev] = sites(rev)
        counts = record["counts"][rev] = dict(Counter(site["file"] for site in found))
        record["totals"][rev] = len(found)
        record["revisions"][rev] = rev if rev == WORKTREE else git("rev-parse", rev).strip()
        print(f"== {rev}")
        print("".join(f"{s['file']}:{s['line']}: [{s['rule']}] {s['test']}\n"
                      for s in found) if args.list else "", end="")
        print("".join(f"{path:<45}{n:>5}\n" for path, n in counts.items()), end="")
        print(f"{'TOTAL':<45}{len(found):>5}")
    if not args.no_write:
        out = ROOT / "benchmarks" / "model_kind_branches.json"
        out.write_text(json.dumps(record, indent=1) + "\n")
        print(f"wrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
