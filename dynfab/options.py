"""The options of a run, one list for `dynfab run` and `dynfab.run` alike.

Every solver option is a scene key (`[static]` or `[dynamic]`), so the scene a
result file records (its `scene` attribute) is the scene actually run, with
every option applied. `apply_run_options` is the one place that maps an option
to its key, refuses an option the chosen solver would ignore, and re-validates
the scene (`dynfab.scene.validate_scene`), so the command line and the Python
API give the same one-line errors.
"""

from __future__ import annotations

import dataclasses
import difflib

from dynfab.errors import UserError
from dynfab.scene import RUN_OPTIONS, Scene, run_flag, validate_scene

SOLVERS = ("static", "dynamic")

STATIC_OPTIONS = {name: name for name in RUN_OPTIONS["static"]}
"""Option name -> field of `Scene.static` (the keys marked option=True in dynfab.scene)."""

DYNAMIC_OPTIONS = {name: name for name in RUN_OPTIONS["dynamic"]}
"""Option name -> field of `Scene.dynamic` (units and rules: dynfab.scene.Dynamic)."""

SOLVER_OPTIONS = {"static": STATIC_OPTIONS, "dynamic": DYNAMIC_OPTIONS}
ALL_OPTIONS = (*STATIC_OPTIONS, *(k for k in DYNAMIC_OPTIONS if k not in STATIC_OPTIONS))


def run_flags() -> dict[str, tuple[type, str]]:
    """`dynfab run` flag -> (argparse type, help), one per option, from the scene keys."""
    types = {"float": float, "int": int, "str": str}
    flags = {}
    for name in ALL_OPTIONS:
        specs = {solver: RUN_OPTIONS[solver][name] for solver in SOLVERS
                 if name in RUN_OPTIONS[solver]}
        solvers_of = {}  # help text -> the solvers whose key it describes
        for solver, spec in specs.items():
            solvers_of.setdefault(_help(spec), []).append(solver)
        flags[run_flag(name)] = (types[next(iter(specs.values())).kind], "; ".join(
            f"{' or '.join(solvers)} solver: {text}" for text, solvers in solvers_of.items()))
    return flags


def _help(spec) -> str:
    """A key's meaning for --help: its choices first, its unit after its first clause."""
    head, sep, rest = spec.doc.partition("; ")
    text = f"{head} [{spec.unit}]{sep}{rest}" if spec.unit else spec.doc
    if not spec.choices:
        return text
    return f"{', '.join(spec.choices[:-1])} or {spec.choices[-1]}; {text}"


def check_solver(solver: str) -> str:
    """`solver` if it names a solver, else a UserError."""
    if solver not in SOLVERS:
        raise UserError(f"solver = {solver!r}: must be one of {', '.join(SOLVERS)}")
    return solver


def apply_run_options(scene: Scene, solver: str, **options) -> Scene:
    """`scene` with the run options set on its `[static]` or `[dynamic]` table, validated.

    An option given as None is not set. An option the solver does not take (a
    dynamic option with the static solver, or the reverse) or an unknown one is
    a UserError naming it, never silently ignored.
    """
    check_solver(solver)
    given = {name: value for name, value in options.items() if value is not None}
    fields = SOLVER_OPTIONS[solver]
    for name, value in given.items():
        if name not in fields:
            raise _not_an_option(name, value, solver)
    if not given:
        return validate_scene(scene)
    table = getattr(scene, solver)
    updated = dataclasses.replace(table, **{fields[name]: value for name, value in given.items()})
    return validate_scene(dataclasses.replace(scene, **{solver: updated}))


def _not_an_option(name: str, value, solver: str) -> UserError:
    """The error for an option that the solver does not take."""
    flag = run_flag(name)
    other = [s for s in SOLVERS if s != solver and name in SOLVER_OPTIONS[s]]
    if other:
        return UserError(f"{flag} {value}: an option of the {other[0]} solver; the {solver} "
                          f"solver does not use it (pass --solver {other[0]}, or drop it)")
    match = difflib.get_close_matches(name, ALL_OPTIONS, n=1)
    hint = f"; did you mean {match[0]!r}?" if match else ""
    return UserError(f"unknown run option {name!r}{hint} (options: {', '.join(ALL_OPTIONS)})")
