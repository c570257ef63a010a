"""Code lines of dynfab/ and kernels/, per top-level package folder and in total, for one or two
revisions.

Run:  python benchmarks/code_lines.py                            (the working tree)
      python benchmarks/code_lines.py --rev a2b9d22 --rev HEAD   (two commits, and the change)

A code line is a line that holds a token of code: blank lines, comment-only lines and
docstrings (the first statement of a module, class or function when it is a string,
found with `ast`) do not count. The lines come from `tokenize`: every token but
comments, line ends, indents and the docstrings' strings marks the lines it spans (a
multi-line string that is not a docstring counts all its lines). Files: every .py file
under dynfab/ and kernels/ (none under a tests/, benchmarks/ or runs/ folder), read with
`git ls-tree -r --name-only REV` and `git show REV:path` for a revision, from disk for the
working tree (tracked and untracked files that git does not ignore).

A package is the top-level folder of a file under dynfab/ (dynfab/model, dynfab/solvers,
...; "dynfab/*.py" for the modules directly in dynfab/) or "kernels". The layout of dynfab/
may differ between two revisions, so the per-package rows are each revision's own folders
and the TOTAL is what compares them. Prints the table; writes benchmarks/code_lines.json.
"""

from __future__ import annotations

import argparse
import ast
import io
import json
import subprocess
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FOLDERS = ("dynfab", "kernels")
EXCLUDED = {"tests", "benchmarks", "runs"}
WORKTREE = "worktree"
NOT_CODE = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT,
            tokenize.ENCODING, tokenize.ENDMARKER}


def git(*args: str) -> str:
    """The standard output of a git command run at the repository's root."""
    return subprocess.run(["git", *args], cwd=ROOT, check=True, capture_output=True,
                          text=True).stdout


def python_files(rev: str) -> list[str]:
    """The .py paths under dynfab/ and kernels/ at `rev` (WORKTREE: on disk), sorted."""
    if rev == WORKTREE:
        listed = git("ls-files", "--cached", "--others", "--exclude-standard", "--", *FOLDERS)
    else:
        listed = git("ls-tree", "-r", "--name-only", rev, "--", *FOLDERS)
    paths = [p for p in listed.splitlines() if p.endswith(".py")
             and not EXCLUDED.intersection(Path(p).parts[:-1])]
    if rev == WORKTREE:
        paths = [p for p in paths if (ROOT / p).is_file()]  # a deleted tracked file
    return sorted(set(paths))


def read(rev: str, path: str) -> str:
    """The text of `path` at `rev` (WORKTREE: on disk)."""
    if rev == WORKTREE:
        return (ROOT / path).read_text(encoding="utf-8")
    return git("show", f"{rev}:{path}")


def docstring_starts(source: str) -> set[tuple[int, int]]:
    """(line, column) of where each module, class and function docstring's string begins."""
    starts = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if (body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                    and isinstance(body[0].value.value, str)):
                starts.add((body[0].value.lineno, body[0].value.col_offset))
    return starts


def code_lines(source: str) -> int:
    """The number of lines of `source` that hold code (`tokenize`; docstrings left out)."""
    docstrings, lines = docstring_starts(source), set()
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type in NOT_CODE or token.start in docstrings:
            continue
        lines.update(range(token.start[0], token.end[0] + 1))
    return len(lines)


def package(path: str) -> str:
    """The top-level package folder of `path`: dynfab/<name>, "dynfab/*.py" or kernels."""
    parts = Path(path).parts
    if parts[0] == "dynfab":
        return "dynfab/*.py" if len(parts) == 2 else f"dynfab/{parts[1]}"
    return parts[0]


def count(rev: str) -> dict[str, int]:
    """Code lines per package at `rev`."""
    counts: dict[str, int] = {}
    for path in python_files(rev):
        counts[package(path)] = counts.get(package(path), 0) + code_lines(read(rev, path))
    return dict(sorted(counts.items()))


def change(before: int | None, after: int | None) -> str:
    """The change from `before` to `after` in per cent, "" where either is missing."""
    return f"{100.0 * (after - before) / before:+.1f} %" if before and after is not None else ""


def print_table(revs: list[str], counts: dict[str, dict[str, int]]) -> None:
    """Package, lines per revision and (two revisions) the change, then the TOTAL."""
    names = sorted({name for rev in revs for name in counts[rev]})
    print(f"{'package':<20}" + "".join(f"{rev:>12}" for rev in revs)
          + ("    change" if len(revs) == 2 else ""))
    for name in names + ["TOTAL"]:
        cells = [sum(counts[rev].values()) if name == "TOTAL" else counts[rev].get(name)
                 for rev in revs]
        print(f"{name:<20}" + "".join(f"{'-' if c is None else c:>12}" for c in cells)
              + (f"  {change(*cells):>8}" if len(revs) == 2 else ""))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rev", action="append", help="a git revision (repeatable, at most "
                        "two; default: the working tree)")
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args()
    revs = args.rev or [WORKTREE]
    if len(revs) > 2:
        parser.error("at most two --rev")
    counts = {rev: count(rev) for rev in revs}
    print_table(revs, counts)
    totals = {rev: sum(counts[rev].values()) for rev in revs}
    record = {"revisions": {rev: rev if rev == WORKTREE else git("rev-parse", rev).strip()
                            for rev in revs},
              "packages": counts, "totals": totals}
    if len(revs) == 2:
        record["change_percent"] = round(100.0 * (totals[revs[1]] - totals[revs[0]])
                                         / totals[revs[0]], 2)
    if not args.no_write:
        out = ROOT / "benchmarks" / "code_lines.json"
        out.write_text(json.dumps(record, indent=2) + "\n")
        print(f"wrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
