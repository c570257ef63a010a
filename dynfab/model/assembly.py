"""The whole model's energy, gradient and banded Hessian for one yarn (docs/model.md sections 2-4).

V = sum over the terms of `dynfab.model.terms.registry.TERMS` that the yarn has
(`Yarn.active`), each through its module's entry points (`dynfab.model.terms`), in
registry order: E_stretch + E_bend + sum_j E_contact,j (+ sum_j H_j) - W_gravity
- W_load. `P` is the end load [N] (0 under displacement control, where the load term
is absent); `anchors` and `friction_limit` (F_T, frozen) are per crossing. `branch`
(optional, per crossing) holds crossings open or closed (`dynfab.model.terms.contact`);
without it the contact is unilateral.
"""

import importlib
import warnings
from typing import NamedTuple

import numba
import numpy as np
from numba import literal_unroll
from numba.core.errors import NumbaExperimentalFeatureWarning

from dynfab.linalg import banded
from dynfab.model.terms import contact, friction, nodes, registry


class Frozen(NamedTuple):
    """What a Newton solve holds fixed while it assembles V (docs/model.md sections 4, 6); every
    term's entry points take it whole (`dynfab.model.terms`)."""

    load: float
    """The end load P [N]; 0 under displacement control."""
    anchors: np.ndarray
    """Friction anchors xi (C,) [m]."""
    friction_limit: np.ndarray
    """F_T (C,) [N], frozen during the solve."""
    contact_tangent: np.ndarray
    """dR/dg (C,) [N/m] at the positions (`contact_state`), read only when `coupled`."""
    branch: object
    """None (the unilateral contact law) or each crossing's branch (C,) int64
    (`dynfab.model.terms.contact`)."""
    coupled: bool
    """Hessian: add the derivative of F_T through the contact force (`friction.add_limit_coupling`)."""
    secant: bool
    """Hessian: sliding crossings get the secant stiffness F_T / |s| (`friction.add_hessian`)."""


YARN_TERMS = tuple(i for i, t in enumerate(registry.TERMS) if t.yarn)
"""The registry index of each term with one-yarn entry points (`registry.Term.yarn`), in
registry order: the k-th entry point below is term YARN_TERMS[k]'s."""


def _entry_points(name: str) -> tuple:
    """The entry point `name` of the numba module `dynfab.model.terms.<term>` of every term
    in YARN_TERMS, registry order."""
    return tuple(getattr(importlib.import_module(f"dynfab.model.terms.{registry.TERMS[i].name}"),
                         name) for i in YARN_TERMS)


NODE_TERMS = np.array(nodes.INDICES, np.int64)
"""The registry index of each node term (`dynfab.model.terms.nodes`), summed after the others."""
ENERGIES = _entry_points("yarn_energy")
GRADIENTS = _entry_points("add_yarn_gradient")
HESSIANS = _entry_points("add_yarn_hessian")
"""The terms' entry points, unrolled by `literal_unroll` below: one direct call per term."""

# literal_unroll types the tuple's items one at a time and calls each dispatcher directly;
# its item lookup still asks numba's first-class function types to unify the dispatchers,
# which warns at compile time. Nothing here uses first-class functions.
warnings.filterwarnings("ignore", message="First-class function type feature is experimental",
                        category=NumbaExperimentalFeatureWarning)

TERM_COUNT = len(registry.TERMS)
"""Entries of the energy vector, one per term in registry order (`registry.index`)."""


@numba.njit(cache=True)
def _check_terms(yarn):
    """numba's cache does not notice a change of the registry: code compiled for another term
    list must not run on yarns built from this one."""
    if yarn.active.size != TERM_COUNT:
        raise RuntimeError("the numba cache of dynfab.model.assembly predates the term registry: "
                           "delete the stale *.nbi / *.nbc files")


@numba.njit(cache=True)
def energy_vector():
    """A zero energy vector (TERM_COUNT,) [J] for `energies`."""
    return np.zeros(TERM_COUNT)


@numba.njit(cache=True)
def energies(pos, yarn, P, anchors, friction_limit, out, branch=None):
    """Each term's energy [J] into out (TERM_COUNT,), registry order; a term the yarn lacks is 0."""
    _check_terms(yarn)
    frozen = Frozen(P, anchors, friction_limit, anchors[:0], branch, False, False)
    k = 0
    for energy in literal_unroll(ENERGIES):
        term = YARN_TERMS[k]
        out[term] = energy(pos, yarn, frozen) if yarn.active[term] else 0.0
        k += 1
    if NODE_TERMS.size:
        node_energies = np.zeros(NODE_TERMS.size)
        nodes.energies(pos, yarn.rest_position, yarn.node_parameters, yarn.node_term_active,
                       node_energies)
        out[NODE_TERMS] = node_energies


@numba.njit(cache=True)
def gradient(pos, yarn, P, anchors, friction_limit, grad, branch=None):
    """grad = dV/dr (N+1, 2) [N], F_T frozen."""
    _check_terms(yarn)
    grad[:, :] = 0.0
    frozen = Frozen(P, anchors, friction_limit, anchors[:0], branch, False, False)
    k = 0
    for add_gradient in literal_unroll(GRADIENTS):
        if yarn.active[YARN_TERMS[k]]:
            add_gradient(pos, yarn, frozen, grad)
        k += 1
    nodes.add_gradient(pos, yarn.rest_position, yarn.node_parameters, yarn.node_term_active, grad)


@numba.njit(cache=True)
def hessian(pos, yarn, anchors, friction_limit, contact_tangent, coupled, band, secant=False,
            branch=None):
    """band = d2V/dr2 [N/m], banded (`dynfab.linalg.banded`), F_T frozen.

    With `coupled`, adds the derivative of F_T through the contact force on
    sliding crossings (`friction.add_limit_coupling`, dR/dg from `contact_tangent`):
    the Jacobian of the coupled friction problem, no longer symmetric. With `secant`,
    sliding crossings get the secant stiffness F_T / |s| (`friction.add_hessian`).
    """
    _check_terms(yarn)
    band[:, :] = 0.0
    frozen = Frozen(0.0, anchors, friction_limit, contact_tangent, branch, coupled, secant)
    k = 0
    for add_hessian in literal_unroll(HESSIANS):
        if yarn.active[YARN_TERMS[k]]:
            add_hessian(pos, yarn, frozen, band)
        k += 1
    nodes.add_band(pos, yarn.rest_position, yarn.node_parameters, yarn.node_term_active, band)


@numba.njit(cache=True)
def contact_state(pos, yarn, contact_force, friction_limit, contact_tangent, branch=None):
    """R_j [N], F_T,j [N] (Gralen, 0 without friction) and dR/dg [N/m] of every crossing."""
    has_friction = yarn.active[friction.INDEX]
    for j in range(yarn.crossing_node.size):
        g = contact.closure(pos, yarn.crossing_node[j], yarn.crossing_side[j], yarn.gap_offset[j])
        on = contact.branch_of(branch, j)
        R = contact.force_on_branch(g, yarn.contact_law, on)
        contact_force[j] = R
        contact_tangent[j] = contact.tangent_on_branch(g, R, yarn.contact_law, on)
        friction_limit[j] = 0.0
        if has_friction:
            friction_limit[j] = friction.limit(R, yarn.friction_alpha, yarn.friction_constant,
                                               yarn.friction_onset)


@numba.njit(cache=True)
def contact_state_of(pos, yarn, branch=None):
    """`contact_state` into new arrays: (R_j [N], F_T,j [N], dR/dg [N/m]), (C,) each."""
    c = yarn.crossing_node.size
    contact_force, friction_limit, contact_tangent = np.zeros(c), np.zeros(c), np.zeros(c)
    contact_state(pos, yarn, contact_force, friction_limit, contact_tangent, branch)
    return contact_force, friction_limit, contact_tangent


def tangent(pos, yarn, anchors, coupled: bool) -> np.ndarray:
    """The banded tangent [N/m] of one yarn at `pos` (`hessian`, `dynfab.linalg.banded` layout): F_T
    and dR/dg from the contact state there, the friction anchors of the step's start; with
    `coupled` the coupled friction Jacobian."""
    pos = np.ascontiguousarray(pos, dtype=np.float64)
    _, friction_limit, contact_tangent = contact_state_of(pos, yarn)
    band = banded.zeros_band(pos.size)
    hessian(pos, yarn, np.ascontiguousarray(anchors, dtype=np.float64), friction_limit,
            contact_tangent, coupled, band)
    return band
