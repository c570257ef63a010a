"""What a fit needs of each model (docs/model.md "Fitting parameters"): its fittable keys,
the start value of a key the scene leaves to a default, and the solve of a load path.

- the one-yarn model (`YarnFit`): the path solved by `dynfab.fitting.sensitivity.solve_path`, whose
  exact sensitivities give the Jacobian;
- the woven fabric (`FabricFit`): the path solved through the run contract
  (`dynfab.solvers.contract.RunModel`: `make_solver(build_model(scene), "static")`, one step per
  load of the path, the model's domain check after each, as a run), the measured columns read from
  the step records (`dynfab.results.measured_curve.Column.read`). It has no exact sensitivities: its
  Jacobian is a forward difference of whole path solves (`dynfab.fitting.fit`).

`fit_model(scene)` picks one, by geometry.model.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dynfab import scene as scene_module
from dynfab.errors import UserError
from dynfab.model.builders import scene_kind
from dynfab.results.measured_curve import measurable

FABRIC_TABLES = ("warp", "weft", "friction", "contact", "gravity", "crossing")
"""The tables whose real keys a fabric's fit may vary (the material, the crossings' laws,
gravity); geometry and load are the experiment's, not the material's."""


@dataclass
class PathCurves:
    """A solved load path as the fit reads it."""

    observables: dict = field(default_factory=dict)
    """name -> (steps,) the measured column's value at each step of the path."""


class YarnFit:
    """The one-yarn model: the sweepable keys, the exact sensitivities."""

    model = "yarn"
    exact = True
    """Whether `dynfab.fitting.sensitivity` differentiates its paths exactly."""

    @staticmethod
    def fittable_keys(scene) -> tuple[str, ...]:
        """Numeric, sweepable keys whose table the scene has (docs/model.md section 1)."""
        return tuple(k for k in scene_module._SWEEPABLE
                     if getattr(scene, k.split(".")[0]) is not None)

    @staticmethod
    def default_value(scene, key: str) -> float | None:
        """The value a key left out of the scene takes (None: none to start from)."""
        if key == "friction.stick_stiffness":  # EA / (L/N)
            from dynfab.model.builders import build_model
            return float(build_model(scene).yarns[0].stick_stiffness)
        return None

    @staticmethod
    def solve(scene, names):
        """The path's `dynfab.fitting.sensitivity.PathSolution` (its observables hold every
        name)."""
        from dynfab.fitting.sensitivity import solve_path
        return solve_path(scene)


def _unused_compaction(scene, table: str, name: str) -> bool:
    """Whether `table.name` is a key of a family's lateral compaction that the family does not
    have (docs/model.md 11.5: all four keys or none; one alone is refused)."""
    family = getattr(scene, table, None)
    return (name in scene_module.COMPACTION_KEYS
            and getattr(family, "fibre_modulus", None) is None)


class FabricFit:
    """The woven fabric: the real keys of FABRIC_TABLES, solved through the run contract."""

    model = "fabric"
    exact = False

    @staticmethod
    def fittable_keys(scene) -> tuple[str, ...]:
        """The real keys of FABRIC_TABLES that the scene's kind takes (`scene_takes`: a
        specimen's without the layout keys its [specimen] sets, a planar fabric's without the
        spatial ones), whose table the scene has."""
        return tuple(f"{table}.{name}" for table in FABRIC_TABLES
                     if getattr(scene, table, None) is not None
                     for name, spec in scene_module._SCHEMA[table][1].items()
                     if spec.kind == "float" and scene_module.scene_takes(scene, table, name)
                     and not _unused_compaction(scene, table, name))

    @staticmethod
    def default_value(scene, key: str) -> float | None:
        """What the fabric runs for a key the scene leaves out (docs/model.md section 10):
        the core stiffness's and stick stiffness's defaults as the structure holds them, the
        wefts' default linear density."""
        from dynfab.model.builders.fabric import families
        from dynfab.model.builders import build_model

        if key == "weft.linear_density":
            return float(families(scene)[1].linear_density)
        if key in ("contact.core_stiffness", "friction.stick_stiffness"):
            structure = build_model(scene).structure
            law = (structure.tie_contact_law[:, 0] if key.startswith("contact")
                   else structure.tie_friction_law[:, -1])
            return float(law[0])
        return None

    @staticmethod
    def solve(scene, names) -> PathCurves:
        """The measured columns `names` along the scene's load path, by the static solver
        through the run contract; a step that leaves the model's domain raises SolverError
        (`FabricModel.check_step`), as in a run."""
        from dynfab.model.builders import build_model
        from dynfab.solvers.by_name import make_solver

        columns = {name: measurable(scene_kind(scene))[name] for name in names}
        model = build_model(scene)
        solver = make_solver(model, "static")
        state = model.initial_state()
        values = {name: [] for name in names}
        for index in range(len(model.load_values)):
            state, record = solver.step(state, model.step_load(index))
            model.check_step(record)
            if index < model.relaxation_steps:
                continue  # a specimen's step 0, the preload relaxed: no point of the curve
            for name, column in columns.items():
                values[name].append(column.read(record))
        return PathCurves({name: np.asarray(v) for name, v in values.items()})


FITS = {"yarn": YarnFit, "fabric": FabricFit, "specimen": FabricFit}
"""Each kind of scene's fit (`scene_kind`)."""


def fit_model(scene):
    """The fit's view of the scene's model: `YarnFit` or `FabricFit` (a specimen's too)."""
    return FITS[scene_kind(scene)]


def start_value(scene, key: str) -> float:
    """The scene's value of `key`, or where it leaves it out, what its model runs."""
    table, name = key.split(".")
    value = getattr(getattr(scene, table), name)
    if value is None:
        value = fit_model(scene).default_value(scene, key)
    if value is None:
        raise UserError(f"--fit {key}: the scene leaves it out and there is no value to start "
                        f"from; write {name} = ... under [{table}]")
    return float(value)
