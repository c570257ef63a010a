"""What every solver offers a run: two contracts (`typing.Protocol`), one per way of driving it.

`dynfab.run` drives a solver through these contracts only; no solver module
imports another, and the load a step prescribes comes from the model side
(`dynfab.model.loading`), not from a solver.

`Solver`, by load step: the static reference (`dynfab.solvers.static.StaticSolver`)
and the dynamic relaxation (`dynfab.solvers.dynamic.DynamicSolver`). Each call of
`step(state, load)` takes the equilibrium of the previous load step to the
equilibrium under the next load value of the path (docs/model.md sections 5, 6).

`Transient`, by time: the dynamic solver's transient mode
(`dynfab.solvers.dynamic.DynamicTransient`, docs/model.md section 5). It is a sibling contract,
not the same one, because a transient run is one time integration over the
whole load path: the load ramps in time, the state between two outputs holds
velocities that live in the integrator (State has none), and the outputs are
frames at output times, not one record per load value. It yields every frame
as soon as it is computed, so a run can write each one to disk at once.

A solver object conforms to one contract or the other, never both, so
`isinstance(engine, Transient)` tells a run which way to drive it (the
contracts are `runtime_checkable`: the check looks for the members by name,
their signatures are this module's documentation).
"""

from __future__ import annotations

from typing import Iterator, Mapping, Protocol, runtime_checkable

import numpy as np

from dynfab.errors import SolverError
from dynfab.model.state import State
from dynfab.scene import Scene
from dynfab.model.step import StepSolution, StepStart
from dynfab.model.structure import Structure, sliding

Record = dict[str, np.ndarray]
"""One finished load step: dataset name -> array, written as `steps/<name>` (one row per
step) of the result file (`dynfab.results.file` UNITS lists every name with its units)."""

Frame = dict[str, np.ndarray]
"""One transient output: dataset name -> array, written as `frames/<name>` of the result file."""

STEP_KEYS = ("load", "end_force", "end_displacement", "positions", "contact_force",
             "friction_force", "friction_limit", "sliding", "anchors", "dissipated", "crimp",
             "residual", "iterations", "rounding_floor", "stable", "buckled",
             "lowest_eigenvalue", "lowest_eigenvalue_error", "error_estimate", "slip_ratio")
"""Names every `Solver.step` record holds, whatever the solver, besides one
`energy/<term>` per reported energy term (`dynfab.model.observables`) and, where the scene has a
weft, stress [N/m] (yarns,), the end force per unit width; shapes (yarns, ...) with
yarns = model.yarn_count:

- by `dynfab.model.observables.finish_step`: load [N or m], end_force [N],
  end_displacement [m], dissipated [J], crimp [-], residual [N], iterations
  [-] and slip_ratio [-] (the largest over the crossings, `dynfab.model.domain.slip_ratios`)
  (yarns,); positions [m] (yarns, N+1, 2); contact_force, friction_force,
  friction_limit [N], sliding [-] (bool) and anchors [m] (yarns, crossings);
- by the solver's certificate (`dynfab.solvers.certificate.StepStability.fields`,
  docs/model.md section 6): stable, buckled [-] (bool), lowest_eigenvalue [N/m] (the
  lowest eigenvalue of the frozen-F_T Hessian on the free dofs, an upper bound of it),
  lowest_eigenvalue_error [N/m] (lambda_min lies in [lowest_eigenvalue - error,
  lowest_eigenvalue]) and error_estimate [m] (residual x est ||H^-1||_inf) (yarns,);
  rounding_floor [-] (yarns,) bool: the residual stopped falling above the tolerance.
  (A fabric's record holds them too, one scalar per step for its patch,
  `dynfab.model.fabric.model`.)

A solver may add its own names (the dynamic solver: time_steps, force_evaluations,
dt [s], tolerance [N], negative_eigenvalues of the certificate's Hessian and, semi-implicit,
cg_iterations), each listed in `dynfab.results.file.UNITS`. `dynfab.run` adds
wall_time [s] (a scalar per step) after the step returns."""

FRAME_KEYS = ("time", "positions", "velocities", "force", "contact_force", "anchors",
              "energy/kinetic")
"""Names every `Transient` frame holds, besides `energy/<term>` per reported term: time [s]
(scalar), positions [m], velocities [m/s] and force [N], contact_force [N] and anchors [m],
energy/kinetic [J], each in the model's record layout (`dynfab.model.record_layout`: a one-yarn
model's (yarns, N+1, 2), (yarns, crossings) and (yarns,))."""


@runtime_checkable
class RunModel(Protocol):
    """What a run (`dynfab.run`) needs of a model, whatever its kind: the one-yarn model
    (`dynfab.model.yarn.Model`), the woven fabric's (`dynfab.model.fabric.model.FabricModel`)
    and the shear specimen's (`dynfab.model.fabric.specimen_model.SpecimenModel`) fulfil it,
    built by `dynfab.model.builders.build_model` from a scene, so the run never asks
    which model it drives (its solvers come from `dynfab.solvers.by_name.make_solver`). (Members
    looked up by name, as for the solvers below.)"""

    scene: Scene
    structure: Structure
    """The scene's chains, ties and held dofs (`dynfab.model.structure`)."""
    control: str
    """"force" or "displacement"."""
    load_values: np.ndarray
    """The load path, one row (or value) per step [N or m]."""
    relaxation_steps: int
    """Steps before the scene's load path (a specimen's step 0, its preload relaxed)."""
    history_keys: tuple
    """The step datasets of the whole path that `state_from_step` needs to resume."""

    def step_load(self, index: int):
        """The load of step `index`: what the model's `Solver.step` takes."""

    def attrs(self) -> dict:
        """The model's root attributes of a result file (`yarn_labels`, lengths, terms, ...)."""

    def reference(self) -> dict:
        """The result file's `reference/` group: the as-woven state and the crossing nodes."""

    def initial_state(self):
        """The as-woven state a run starts from."""

    def state_from_step(self, last: dict, history: dict | None = None):
        """The state a finished step (a record read back from a file) left; `history` the
        columns `history_keys` of every finished step, {name: (steps, ...)}."""

    def point_data(self, entry: dict) -> dict:
        """The XDMF view's nodal point data of a step or frame (`dynfab.results.xdmf`)."""

    def check_step(self, record: dict) -> None:
        """Raise `dynfab.errors.SolverError` if the step left the model's domain."""

    groups: list
    """The structure's independent groups of chains, each an array of chain indices (a
    one-yarn model's yarns, a fabric's one patch): a solver reports its fields per group."""

    def group_name(self, k: int) -> str:
        """Group k (0-based) as a message names it ("yarn 2", "fabric")."""

    def start_of_step(self, state, load) -> StepStart:
        """Where the step to `load` starts from `state` (not modified)."""

    def finish_step(self, state, start: StepStart, solution: StepSolution):
        """(the new state, the step's record) from the solver's `solution` of the step that
        `start` began: the anchors return-mapped (docs/model.md section 4), the observables
        (`STEP_KEYS`), the solver's fields, in the model's record layout."""

    def frame(self, time: float, arrays: dict) -> dict:
        """A transient frame (`FRAME_KEYS`, in the model's layout) at `time` [s] from the
        structure's flat arrays: positions, velocities, force (n, 2), anchors (T, 2) and the
        kinetic energy per group (`dynfab.kernels.structure_relaxation`'s frames)."""

    def frame_arrays(self, frame: dict) -> dict:
        """The structure's flat arrays of a frame this model made (positions, velocities,
        force, anchors, time): what a resumed transient restores."""

    def transient_drive(self):
        """What a transient drives (`dynfab.model.loading.Drive`): the path of each load
        family's end load or displacement, or of a specimen's held nodes."""


@runtime_checkable
class Solver(Protocol):
    """Takes the model's yarns from one equilibrium to the next, one load value at a time.

    The model (`dynfab.model.yarn.Model`) is given when the solver is built and does not change.
    """

    name: str
    """The solver's name, the result file's `solver` attribute ("static", "dynamic")."""

    def attrs(self) -> dict:
        """Root attributes of the result file describing the solver and its options."""

    def step(self, state: State, load: float) -> tuple[State, Record]:
        """Relax every yarn under `load`, starting from `state`; return (new state, record).

        `state` is the previous equilibrium (`dynfab.model.yarn.initial_state` for the first
        step): positions [m] (yarns, N+1, 2), friction anchors [m] (yarns, crossings) held
        during the step, dissipated [J] and the last load (yarns,). `load` is the next
        value of the load path: the end force P [N] under force control, the end
        displacement u [m] under displacement control. The step starts from
        `dynfab.model.loading.prescribe_load(model, state, load)` and ends, once every yarn's
        residual (largest free force component, friction included) is within tolerance
        and certified, with `dynfab.model.observables.finish_step`: the new state has the
        anchors return-mapped (docs/model.md section 4) and `load` applied; the record holds
        `STEP_KEYS`. `state` is not modified.

        Raises `dynfab.errors.SolverError` (one line naming the yarn and the cause) when a
        yarn cannot reach the answer: divergence, iteration or time-step limit, an error
        bound above the accuracy target. Nothing of a failed step is returned. (A solver
        asked to step a scene it integrates in time, a DynamicSolver built for
        dynamic.mode = "transient", raises `dynfab.errors.UserError` instead.)
        """


@runtime_checkable
class Transient(Protocol):
    """Integrates the equations of motion in physical time over the whole load path."""

    name: str
    """The solver's name, the result file's `solver` attribute."""

    def attrs(self) -> dict:
        """Root attributes of the result file describing the solver and its options."""

    def advance(self, state: State, resume_from: Mapping | None = None) -> Iterator[Frame]:
        """Run from `state` (at t = 0, at rest, zero load) to the scene's duration, the load
        following `dynfab.model.loading.load_at_time`; yield every output frame (`FRAME_KEYS`)
        as it is reached: t = 0, every output interval, the duration.

        `resume_from`, the last frame a previous run of the same scene wrote, continues
        that run: the frames after it are yielded, the same as an uninterrupted run's.

        Raises `dynfab.errors.SolverError` when the integration diverges; the frames
        yielded before stay valid.
        """


SLIDING_HALVINGS = 4
"""How many times a load step of a structure whose crossings slide is cut in half where it
fails (`step_in_halves`): a yarn end may pass its last crossing within a step, whose
equilibrium then needs the crossing gone (docs/model.md 11.13); down to 1/16 of the step."""


def step_in_halves(step_once, model, state, load, halvings: int = SLIDING_HALVINGS,
                   say=None):
    """`step_once(state, load)`, or where the model's crossings slide and it fails
    (SolverError), the step made of two halves, each the same way (at most `halvings`
    deep), the crossings a yarn end has passed leaving between them: the record is the last
    half's, the state has every half's dissipation and work. `say(text)` is told of each
    halving (or None)."""
    try:
        return step_once(state, load)
    except SolverError as failed:
        if not (halvings and sliding(model.structure)):
            raise
        middle = 0.5 * (np.asarray(state.load, float) + np.asarray(load, float))
        if say is not None:
            say(f"the step failed ({failed}); the step in two halves, from load {middle}")
        half, _ = step_in_halves(step_once, model, state, middle, halvings - 1, say)
        return step_in_halves(step_once, model, half, load, halvings - 1, say)
