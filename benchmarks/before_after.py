"""Speed of this tree against an earlier commit, measured in one run (benchmarks/static.py,
benchmarks/fabric.py).

Run:  python benchmarks/before_after.py --before REV [--rounds 2] [--sizes 4,8,16,32]
      [--out benchmarks/before_after.json]   (prints a table, writes the JSON file)

Each tree (REV, extracted with `git archive`, and this working tree, copied) runs its own
benchmark scripts from a temporary folder with that folder first on PYTHONPATH (a link
dynfab/kernels -> kernels stands in for the install's package-dir), in turns: before, after,
before, after, ... (`--rounds` turns each), so that both see the same load on this shared
machine. A figure is the best of its turns (the least disturbed). Figures:

- static: `benchmarks/static.py`'s one equilibrium of the paper's yarn (`StaticSolver.step`,
  the banded path), its certificate, and the 40-step traction curves of runs/paper_fig5.toml
  with and without friction;
- fabric: `benchmarks/fabric.py`'s one load step of a clamped n x n patch per size (`--size n`,
  the script's own subprocess of one size), static (`step_s`), dynamic explicit (`step_s`)
  and semi-implicit (`step_s`).

The aim of the issue "One model for the yarn and the fabric": after / before at most 1.1 for
every figure.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUTPUT = Path(__file__).resolve().parent / "before_after.json"
STATIC_FIGURES = {"equilibrium_s": ("equilibrium", "time_s"),
                  "certificate_s": ("certificate", "time_s"),
                  "traction_friction_on_s": ("traction_curve", "friction_on", "time_s"),
                  "traction_friction_off_s": ("traction_curve", "friction_off", "time_s")}
"""Figure name -> its path in benchmarks/static.json."""
FABRIC_PARTS = ("static", "dynamic", "semi")
"""benchmarks/fabric.py's parts timed per size (each part's `step_s`)."""


def extract_before(rev: str, into: Path) -> Path:
    """Commit `rev`'s files in `into`/before."""
    tree = into / "before"
    tree.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    return link_kernels(tree)


def copy_after(into: Path) -> Path:
    """This working tree's tracked and unignored files in `into`/after."""
    tree = into / "after"
    files = subprocess.run(["git", "-C", str(ROOT), "ls-files", "--cached", "--others",
                            "--exclude-standard"], check=True, capture_output=True,
                           text=True).stdout.split()
    for name in files:
        source = ROOT / name
        if source.is_file():
            (tree / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, tree / name)
    return link_kernels(tree)


def link_kernels(tree: Path) -> Path:
    """dynfab/kernels -> ../kernels: `import dynfab.kernels` from the source folder."""
    link = tree / "dynfab" / "kernels"
    if not link.exists():
        link.symlink_to(Path("..") / "kernels")
    return tree


def run_in(tree: Path, arguments: list[str]) -> str:
    """stdout of `python TREE/benchmarks/ARGUMENTS...` with TREE first on PYTHONPATH (its own
    dynfab, checked)."""
    env = {**os.environ, "PYTHONPATH": str(tree), "PYTHONDONTWRITEBYTECODE": "1"}
    check = subprocess.run([sys.executable, "-c", "import dynfab, dynfab.kernels; "
                            "print(dynfab.__file__, dynfab.kernels.__file__)"],
                           env=env, capture_output=True, text=True, check=True, cwd=tree).stdout
    assert all(path.startswith(str(tree)) for path in check.split()), check
    done = subprocess.run([sys.executable, str(tree / "benchmarks" / arguments[0]),
                           *arguments[1:]], env=env, capture_output=True, text=True, cwd=tree)
    if done.returncode:
        raise SystemExit(f"{tree.name}: {' '.join(arguments)} failed:\n{done.stderr[-3000:]}")
    return done.stdout


def static_figures(tree: Path) -> dict:
    """The figures of one run of `benchmarks/static.py` in `tree`."""
    run_in(tree, ["static.py"])
    result = json.loads((tree / "benchmarks" / "static.json").read_text())
    figures = {}
    for name, path in STATIC_FIGURES.items():
        value = result
        for key in path:
            value = value[key]
        figures[name] = value
    return figures


def fabric_figures(tree: Path, n: int) -> dict:
    """The figures of one run of `benchmarks/fabric.py --size n` in `tree`."""
    out = run_in(tree, ["fabric.py", "--size", str(n), "--parts", ",".join(FABRIC_PARTS)])
    lines = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    rows = {line["part"]: line for line in lines if line.get("part") in FABRIC_PARTS}
    return {f"fabric_{n}_{part}_step_s": rows[part]["step_s"] for part in FABRIC_PARTS
            if part in rows and "step_s" in rows[part]}


def best_of(turns: list[dict]) -> dict:
    """Each figure's least value over the turns [s]."""
    return {name: min(turn[name] for turn in turns if name in turn)
            for name in {name for turn in turns for name in turn}}


def _pardiso_after() -> bool:
    """Whether this tree factors the fabric by PARDISO here (MKL installed, DYNFAB_PARDISO
    not 0: `dynfab.linalg.pardiso`); the before tree may predate it."""
    from dynfab.linalg import pardiso
    return pardiso.available()


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", required=True, help="the earlier commit (any git revision)")
    parser.add_argument("--rounds", type=int, default=2, help="turns of each tree")
    parser.add_argument("--sizes", default="4,8,16,32", help="fabric patch sizes n (n x n yarns)")
    parser.add_argument("--out", type=Path, default=OUTPUT, help="the JSON file written")
    args = parser.parse_args(argv)
    sizes = [int(n) for n in args.sizes.split(",") if n]
    revision = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", args.before],
                              check=True, capture_output=True, text=True).stdout.strip()
    loads = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory() as scratch:
        trees = {"before": extract_before(args.before, Path(scratch)),
                 "after": copy_after(Path(scratch))}
        turns = {"before": [], "after": []}
        for round_ in range(args.rounds):
            for which in ("before", "after"):
                figures = static_figures(trees[which])
                for n in sizes:
                    figures.update(fabric_figures(trees[which], n))
                turns[which].append(figures)
                loads.append(os.getloadavg()[0])
                print(f"round {round_ + 1}, {which}: done (load {loads[-1]:.2f})", flush=True)
    before, after = best_of(turns["before"]), best_of(turns["after"])
    rows = {name: {"before_s": before[name], "after_s": after[name],
                   "after_over_before": after[name] / before[name]}
            for name in sorted(before) if name in after}
    result = {"before": revision, "rounds": args.rounds, "sizes": sizes, "load_1min": loads,
              "pardiso_after": _pardiso_after(), "figures": rows, "turns": turns}
    print(f"\n{'figure':32s} {'before [s]':>12s} {'after [s]':>12s} {'after/before':>13s}")
    for name, row in rows.items():
        print(f"{name:32s} {row['before_s']:12.4g} {row['after_s']:12.4g} "
              f"{row['after_over_before']:13.3f}")
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"\nwrote {args.out}")
    return result


if __name__ == "__main__":
    main()
