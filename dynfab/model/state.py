"""What changes during a run, for every model: one `State` (docs/model.md, "The structure").

A model (`dynfab.model.yarn.Model`, `dynfab.model.fabric.model.FabricModel`,
`dynfab.model.fabric.specimen_model.SpecimenModel`) does not change during a run; a State does.
Every model's state holds the same fields in the same layout, its structure's (the solvers never
read them: they see a step's `dynfab.model.step.StepStart`); a result file's layout of them (a
one-yarn model's yarns, a fabric's warps and wefts) is a view, the model's `record_layout`
(`dynfab.model.record_layout`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from dynfab.model.structure import Structure, chain_count
from dynfab.model.terms.kinematics import woven_anchors, woven_state


@dataclass
class State:
    """What changes during a run: the structure's dofs, the friction anchors, the energy friction
    has dissipated and the loads' work, the load the state is at and its end forces; a shear
    specimen's path so far."""

    positions: np.ndarray
    """The structure's dofs (n, dim) [m], its nodes in chain order (a one-yarn model's yarns, a
    fabric's warps then wefts, a specimen's chains); where the crossings slide, their slots hold
    the material's slides (docs/model.md 11.13)."""
    anchors: np.ndarray
    """Friction anchors per tie (T, k) [m] (docs/model.md sections 4, 10, 11.4): the slip of the
    tie's node along its yarn(s), relative to the as-woven slip where a fabric's planes are (a
    one-yarn model's second column 0; a specimen's third the rotation anchor [rad]); where the
    crossings slide, the slides."""
    dissipated: np.ndarray
    """Cumulative friction dissipation of each group (`RunModel.groups`: a one-yarn model's
    yarns, a fabric's or a specimen's one) (groups,) [J]."""
    load: np.ndarray
    """The load values the state is at [N or m]: a one-yarn model's per yarn (yarns,), a
    fabric's (warp, weft) (2,), a specimen's d (1,); 0 as woven."""
    end_force: np.ndarray
    """The end force of each loaded end [N]: each yarn's along its axis (yarns,) (the load
    under force control, else the reaction), a specimen's clamp force (1,)."""
    work: float = 0.0
    """Work of the end loads (a fabric's) or of the clamp (a specimen's) so far, trapezoid rule
    over the load steps [J]; 0 where the model does not record it (the one-yarn model)."""
    reference_angle: np.ndarray | None = None
    """A specimen's crossings' shear angles from the as-woven state at step 0 (C,) [rad], the
    reference of its reported angles; None before step 0 and in the other models."""
    path: np.ndarray | None = None
    """A specimen's finished steps' (d [m], clamp force [N]) (steps, 2): the bias extension's
    normalisation reads its curve; None in the other models."""
    path_tangent: np.ndarray | None = None
    """A specimen's dofs' change over its last step per unit of d (n, dim) [m/m] (the path's
    secant, `SpecimenModel.start_of_step`); None where there is none."""

    def copy(self) -> "State":
        """A deep copy (every array copied)."""
        return State(**{f.name: _copied(getattr(self, f.name)) for f in fields(self)})


def _copied(value):
    return value.copy() if isinstance(value, np.ndarray) else value


def as_woven_state(structure: Structure, load, groups: int = 1) -> State:
    """The as-woven start of a run of the yarn and the fabric: the dofs as woven
    (`dynfab.model.terms.kinematics.woven_state`), each anchor at zero slip (`woven_anchors`: a
    tie to ground's at its node's as-woven x), nothing dissipated in any of the `groups`, at
    `load` (zeros of the model's load layout), no end force on any chain."""
    return State(woven_state(structure), woven_anchors(structure), np.zeros(groups),
                 np.array(load, float), np.zeros(chain_count(structure)))


def initial_state(model) -> State:
    """A one-yarn model's as-woven start (`as_woven_state`): each yarn a group, at no load."""
    return as_woven_state(model.structure, np.zeros(model.yarn_count), model.yarn_count)
