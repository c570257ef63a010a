"""Node terms: an energy of each node alone, e(x_i, X_i, p_i), summed over the nodes by one
assembler for every model (docs/model.md, "Node terms").

A node term is a registry entry with `node=True` (`dynfab.model.terms.registry.Term`) whose
module `dynfab.model.terms.<name>` has
- PARAMETERS: the names of its parameters per node (their units in its docstring);
- `parameters(scene, structure)`: (n, len(PARAMETERS)) float, each node's;
- numba `energy(x, rest, p)` -> e [J], `add_gradient(x, rest, p, g)` (g (dim,) += de/dx [N])
  and `add_hessian(x, rest, p, H)` (H (dim, dim) += d2e/dx2 [N/m]), x and rest a node's
  position and as-woven position (dim,) [m], p its parameters (len(PARAMETERS),);
- `warp(scalar, vec)`: its Warp form (`dynfab.kernels.node_terms`).

Adding one is its module and its registry entry: the builders attach its parameters to the
structure (`attach`: `Structure.node_parameters`, side by side in registry order, and
`node_term_active`), the one-yarn, planar and spatial assemblies sum it through the functions
below (its Hessian on each node's own diagonal block), every model records its energy as
`steps/<dataset>`, and the kernels sum its Warp force (`dynfab.kernels.node_terms`).
"""

from __future__ import annotations

import importlib

import numba
import numpy as np
from numba import literal_unroll

from dynfab.linalg.banded import band_add
from dynfab.model.terms import registry

INDICES = tuple(i for i, t in enumerate(registry.TERMS) if t.node)
"""The registry index of each node term, in registry order."""
NAMES = tuple(registry.TERMS[i].name for i in INDICES)
MODULES = tuple(importlib.import_module(f"dynfab.model.terms.{name}") for name in NAMES)
WIDTHS = tuple(len(module.PARAMETERS) for module in MODULES)
"""Each node term's parameter count."""


def attach(scene, structure):
    """`structure` with the parameters of the node terms `scene` has (`Structure`'s
    `node_parameters`, `node_term_active`)."""
    active = np.array([registry.TERMS[i].active(scene) for i in INDICES], np.bool_)
    n = structure.rest_position.shape[0]
    columns = [np.asarray(module.parameters(scene, structure), float).reshape(n, width)
               for module, width, on in zip(MODULES, WIDTHS, active) if on]
    parameters = np.hstack(columns) if columns else np.zeros((n, 0))
    return structure._replace(node_parameters=parameters, node_term_active=active)


def firsts(active: np.ndarray) -> np.ndarray:
    """The first column of each node term's parameters (K,) int64 (-1 where inactive)."""
    out, first = np.full(len(WIDTHS), -1, np.int64), 0
    for k, (width, on) in enumerate(zip(WIDTHS, active)):
        if on:
            out[k], first = first, first + width
    return out


if MODULES:
    ENERGIES = tuple(module.energy for module in MODULES)
    GRADIENTS = tuple(module.add_gradient for module in MODULES)
    HESSIANS = tuple(module.add_hessian for module in MODULES)
    _WIDTHS = np.array(WIDTHS, np.int64)

    @numba.njit(cache=True)
    def energies(pos, rest, parameters, active, out):
        """out[k] = sum_i e_k(x_i, X_i, p_i) [J] of each node term k (K,), 0 where inactive."""
        k, first = 0, 0
        for energy in literal_unroll(ENERGIES):
            out[k] = 0.0
            if active[k]:
                last = first + _WIDTHS[k]
                for i in range(pos.shape[0]):
                    out[k] += energy(pos[i], rest[i], parameters[i, first:last])
                first = last
            k += 1

    @numba.njit(cache=True)
    def add_gradient(pos, rest, parameters, active, grad):
        """grad (n, dim) += de/dx of every active node term at every node [N]."""
        k, first = 0, 0
        for add in literal_unroll(GRADIENTS):
            if active[k]:
                last = first + _WIDTHS[k]
                for i in range(pos.shape[0]):
                    add(pos[i], rest[i], parameters[i, first:last], grad[i])
                first = last
            k += 1

    @numba.njit(cache=True)
    def add_node_hessian(pos, rest, parameters, active, i, H):
        """H (dim, dim) += d2e/dx2 of every active node term at node i [N/m]."""
        k, first = 0, 0
        for add in literal_unroll(HESSIANS):
            if active[k]:
                last = first + _WIDTHS[k]
                add(pos[i], rest[i], parameters[i, first:last], H)
                first = last
            k += 1
else:  # no node term registered: the same calls, doing nothing
    @numba.njit(cache=True)
    def energies(pos, rest, parameters, active, out):
        """No node terms (K = 0)."""

    @numba.njit(cache=True)
    def add_gradient(pos, rest, parameters, active, grad):
        """No node terms."""

    @numba.njit(cache=True)
    def add_node_hessian(pos, rest, parameters, active, i, H):
        """No node terms."""


@numba.njit(cache=True)
def any_active(active) -> bool:
    """Some node term is active."""
    for on in active:
        if on:
            return True
    return False


@numba.njit(cache=True)
def add_band(pos, rest, parameters, active, band):
    """band += each node's d2e/dx2 block on its own dofs (`dynfab.linalg.banded` layout, the
    dofs of node i dim i .. dim i + dim - 1) [N/m]."""
    if not any_active(active):
        return
    d = pos.shape[1]
    H = np.zeros((d, d))
    for i in range(pos.shape[0]):
        H[:, :] = 0.0
        add_node_hessian(pos, rest, parameters, active, i, H)
        for a in range(d):
            for b in range(d):
                band_add(band, d * i + a, d * i + b, H[a, b])
