"""What a finished load step reports (the HDF5 `steps/*` layout), shared by every solver.

`finish_step` takes the relaxed positions of a load step, return-maps the
friction anchors (docs/model.md section 4) and computes the reported quantities: contact
and friction forces, F_T, sliding flags, energies per term, end force and
displacement, crimp, the load per unit width (`stress`, with a weft) and the crossing
nodes' slip ratio.
"""

from __future__ import annotations

import numba
import numpy as np

from dynfab.model import assembly
from dynfab.model.domain import slip_ratios
from dynfab.model.geometry import crimp
from dynfab.model.state import State
from dynfab.model.terms import friction, registry



@numba.njit(cache=True)
def observe_yarn(pos, yarn, P, anchors, contact_force, friction_limit, friction_force, sliding,
                 terms):
    """One yarn's finished step, in one call: contact state, return mapping, energies.

    Fills R, F_T, the friction force and sliding flags, and the energy vector
    (`dynfab.model.assembly` order) after the anchors are return-mapped in place: friction's
    entry is then the energy of its stick springs, 1/2 k_t (x - xi)^2 (|x - xi| <= F_T / k_t).
    Returns (energy dissipated in this step [J], end reaction dV/dx_N [N], the load term
    and friction excluded).
    """
    c = yarn.crossing_node.size
    assembly.contact_state(pos, yarn, contact_force, friction_limit, np.zeros(c))
    lost = 0.0
    if yarn.active[friction.INDEX]:
        lost = friction.return_map(pos, yarn.crossing_node, anchors, friction_limit,
                                   yarn.stick_stiffness, sliding, friction_force)
    assembly.energies(pos, yarn, P, anchors, friction_limit, terms)
    grad = np.zeros_like(pos)
    assembly.gradient(pos, yarn, 0.0, anchors, np.zeros(c), grad)
    return lost, grad[-1, 0]


def finish_step(model, state, positions: np.ndarray, load_value: float,
                residual: np.ndarray, iterations: np.ndarray) -> tuple[State, dict]:
    """The new state (anchors return-mapped) and the step's record for the result file.

    The end force is the applied P under force control, else the reaction dV/dx_N.
    """
    yarns, c = model.yarn_count, model.crossings
    anchors, dissipated = model.per_crossing(state.anchors), state.dissipated.copy()
    record = {name: np.zeros((yarns, c)) for name in
              ("contact_force", "friction_force", "friction_limit")}
    record["sliding"] = np.zeros((yarns, c), dtype=np.bool_)
    reported = _reported_terms(model)
    energies = {registry.TERMS[i].dataset: np.zeros(yarns) for i in reported}
    reaction, terms = np.zeros(yarns), assembly.energy_vector()
    P = load_value if model.control == "force" else 0.0
    for k, yarn in enumerate(model.yarns):
        lost, reaction[k] = observe_yarn(
            positions[k], yarn, P, anchors[k], record["contact_force"][k],
            record["friction_limit"][k], record["friction_force"][k], record["sliding"][k], terms)
        dissipated[k] += lost
        for i in reported:
            energies[registry.TERMS[i].dataset][k] = terms[i]
    loads = np.full(yarns, float(load_value))
    end_force = loads if model.control == "force" else reaction
    if model.width_per_yarn is not None:
        record["stress"] = end_force / model.width_per_yarn
    record.update({
        "load": loads,
        "end_force": end_force,
        "slip_ratio": _slip_ratio(model, positions),
        "end_displacement": positions[:, -1, 0] - model.rest_end_x,
        "positions": positions.copy(),
        "anchors": anchors,
        "dissipated": dissipated,
        "crimp": crimp(positions),
        "residual": np.asarray(residual, float),
        "iterations": np.asarray(iterations, np.int64),
    })
    record.update(energies)
    mapped = model.record_layout.flat_anchors(anchors, state.anchors.shape[1])
    new_state = State(positions=positions.reshape(-1, 2).copy(), anchors=mapped,
                      dissipated=dissipated, load=loads.copy(), end_force=end_force.copy())
    return new_state, record


def _slip_ratio(model, positions: np.ndarray) -> np.ndarray:
    """(yarns,) the largest slip ratio of each yarn's crossing nodes against the weft, fixed
    at its as-woven x (`dynfab.model.domain.slip_ratios`, docs/model.md section 4): recorded, not
    limited, in the one-yarn model (its crossings ride on their nodes, as the paper's)."""
    nodes = model.yarns[0].crossing_node
    return np.max(slip_ratios(positions, nodes, model.crossing_rest_x), axis=1, initial=0.0)


def _reported_terms(model) -> list[int]:
    """Registry indices of the model's terms that report an energy dataset (`Term.dataset`)."""
    return [i for i, t in enumerate(registry.TERMS) if t.name in model.terms and t.dataset]


def frame_observables(model, positions: np.ndarray, anchors: np.ndarray,
                      load_value: float) -> dict:
    """A transient frame's contact forces (yarns, C) [N] and reported energies (yarns,) [J]
    (`energy/<term>`) at `positions` (yarns, N+1, 2) with the `anchors` (yarns, C) the
    integration holds (return-mapped at every time step, so not mapped again here) and the
    load at the frame's time."""
    yarns, c = model.yarn_count, model.crossings
    contact_force, limit = np.zeros((yarns, c)), np.zeros((yarns, c))
    reported = _reported_terms(model)
    out = {registry.TERMS[i].dataset: np.zeros(yarns) for i in reported}
    terms = assembly.energy_vector()
    P = load_value if model.control == "force" else 0.0
    for k, yarn in enumerate(model.yarns):
        assembly.contact_state(positions[k], yarn, contact_force[k], limit[k], np.zeros(c))
        assembly.energies(positions[k], yarn, P, anchors[k], limit[k], terms)
        for i in reported:
            out[registry.TERMS[i].dataset][k] = terms[i]
    out["contact_force"] = contact_force
    return out
