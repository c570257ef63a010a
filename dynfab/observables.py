"""What a finished load step reports (the HDF5 `steps/*` layout), shared by every solver.

`finish_step` takes the relaxed positions of a load step, return-maps the
friction anchors (MODEL.md 4) and computes the reported quantities: contact
and friction forces, F_T, sliding flags, energies per term, end force and
displacement, crimp.
"""

from __future__ import annotations

import numpy as np

from dynfab import assembly
from dynfab.model import Model, State, crimp
from dynfab.terms import friction

ENERGY_TERMS = {"stretch": assembly.STRETCH, "bending": assembly.BENDING,
                "contact": assembly.CONTACT, "gravity": assembly.GRAVITY, "load": assembly.LOAD}
"""Reported energies [J] (`steps/energy/<term>`): the elastic terms, gravity's potential and the
load's potential -P (x_N - x0_N); friction reports its stick springs as `energy/stick` instead."""


def end_force(model: Model, positions: np.ndarray, load_value: float) -> np.ndarray:
    """P per yarn [N]: the applied load, or under displacement control the reaction dV/dx_N."""
    if model.control == "force":
        return np.full(model.yarn_count, load_value)
    grad = np.zeros_like(positions[0])
    reaction = np.empty(model.yarn_count)
    for k, yarn in enumerate(model.yarns):
        c = yarn.crossing_node.size
        assembly.gradient(positions[k], yarn, 0.0, np.zeros(c), np.zeros(c), grad)
        reaction[k] = grad[-1, 0]
    return reaction


def finish_step(model: Model, state: State, positions: np.ndarray, load_value: float,
                residual: np.ndarray, iterations: np.ndarray) -> tuple[State, dict]:
    """The new state (anchors return-mapped) and the step's record for the result file."""
    yarns, c = model.yarn_count, model.crossings
    anchors, dissipated = state.anchors.copy(), state.dissipated.copy()
    record = {name: np.zeros((yarns, c)) for name in
              ("contact_force", "friction_force", "friction_limit", "anchors")}
    record["sliding"] = np.zeros((yarns, c), dtype=np.bool_)
    energies = {name: np.zeros(yarns) for name in _reported_terms(model)}
    tangent, terms = np.zeros(c), np.zeros(6)
    P = load_value if model.control == "force" else 0.0
    for k, yarn in enumerate(model.yarns):
        assembly.contact_state(positions[k], yarn, record["contact_force"][k],
                               record["friction_limit"][k], tangent)
        if yarn.has_friction:
            dissipated[k] += friction.return_map(positions[k], yarn.crossing_node, anchors[k],
                                                 record["friction_limit"][k], yarn.stick_stiffness,
                                                 record["sliding"][k], record["friction_force"][k])
            slip = positions[k, yarn.crossing_node, 0] - anchors[k]
            energies["stick"][k] = 0.5 * yarn.stick_stiffness * np.sum(slip ** 2)
        assembly.energies(positions[k], yarn, P, anchors[k], record["friction_limit"][k], terms)
        for name, index in ENERGY_TERMS.items():
            if name in energies:
                energies[name][k] = terms[index]
    record["anchors"] = anchors
    rest_x_end = model.stacked("rest_position")[:, -1, 0]
    record.update({
        "load": np.full(yarns, float(load_value)),
        "end_force": end_force(model, positions, load_value),
        "end_displacement": positions[:, -1, 0] - rest_x_end,
        "positions": positions.copy(),
        "dissipated": dissipated,
        "crimp": crimp(positions),
        "residual": np.asarray(residual, float),
        "iterations": np.asarray(iterations, np.int64),
    })
    record.update({f"energy/{name}": value for name, value in energies.items()})
    new_state = State(positions=positions.copy(), anchors=anchors, dissipated=dissipated,
                      load=np.full(yarns, float(load_value)))
    return new_state, record


def _reported_terms(model: Model) -> list[str]:
    """Energy names reported for this model: its active terms, friction as `stick`."""
    names = [t for t in model.terms if t != "friction"]
    if "friction" in model.terms:
        names.append("stick")
    return names
