"""The registry of the model's terms: each term declared once (docs/model.md, "Energy").

V = sum over the active terms of their energies. A term is switched on by the
scene (`Term.active`); its numba module (`dynfab.model.terms.<name>`, +dV/dr) is the
static reference. Every term of every model is listed, the spatial kinematics' crossing
rotation spring and lateral contact included (docs/model.md section 11, their elements in
`dynfab.model.terms.spatial`), so every model records the same term under the same
`steps/energy/<...>` name (`energy_records`). A node term (`Term.node`, an energy of each node
alone) is its module and its entry here, and nothing else: every model's assembly and the
kernels sum it (`dynfab.model.terms.nodes`, docs/model.md "Node terms"). The assembly
(`dynfab.model.assembly`), the diagnostics and the result datasets are derived from `TERMS`; adding
a term is its module and one entry here, plus its parameters, if it has new ones: fields of
`dynfab.model.yarn.Yarn` (filled in `build_model`) read from its scene keys (`dynfab.scene`). The
energy vector, `Yarn.active` and the reported `steps/energy/*` follow the entry. The dynamic
solver's Warp kernels compute the terms a `dynfab.model.structure.Structure` holds
(`dynfab.kernels.structure_forces`: stretch, bending, contact, friction, gravity, the
end load), compiled in where the structure has them; a new term joins them there."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class Term:
    """One energy term of the model."""

    name: str
    """Its name, also its module's name in `dynfab.model.terms`. The numba module
    `dynfab.model.terms.<name>` has the entry points `yarn_energy(pos, yarn, frozen)`,
    `add_yarn_gradient(pos, yarn, frozen, grad)` and `add_yarn_hessian(pos, yarn, frozen, band)`
    (`dynfab.model.terms`), which `dynfab.model.assembly` calls in registry order."""
    meaning: str
    """One line: what the term is, with its section of docs/model.md."""
    active: Callable
    """active(scene) -> bool: whether a scene has this term."""
    dataset: str | None
    """The result dataset of its energy [J] (`steps/<dataset>`), or None when it reports none."""
    yarn: bool = True
    """Its module has the one-yarn entry points (`name` above), which the one-yarn assembly
    calls (`dynfab.model.assembly.YARN_TERMS`)."""
    node: bool = False
    """A node term: an energy of each node alone, whose module has the node-term entry points
    (`dynfab.model.terms.nodes`); every model's assembly and the kernels sum it (then `yarn`
    is False)."""


def _always(scene) -> bool:
    return True


def _specimen(scene) -> bool:
    return scene.specimen is not None


TERMS: tuple[Term, ...] = (
    Term("stretch", "extension springs EA/l0 (model.md section 2)", _always, "energy/stretch"),
    Term("bending", "bending springs EI/lbar (model.md section 2)", _always, "energy/bending"),
    Term("contact", "series Kawabata compression at the crossings (model.md section 3)",
         lambda scene: _specimen(scene) or scene.geometry.crossings > 0, "energy/contact"),
    Term("friction", "Huber stick-slip friction at the crossings (model.md section 4)",
         lambda scene: scene.friction is not None, "energy/stick"),
    Term("gravity", "the weight of the yarn's masses (model.md section 2)",
         lambda scene: scene.gravity is not None, "energy/gravity"),
    Term("load", "the end load's potential -P (x_N - x0_N) (model.md section 2)",
         lambda scene: scene.load.control == "force", "energy/load"),
    Term("shear", "the rotation spring of each crossing, K (phi - phi_rest) (model.md 11.3)",
         _specimen, "energy/shear", yarn=False),
    Term("lateral", "the lateral contact of neighbouring yarns (model.md 11.5)", _specimen,
         "energy/lateral", yarn=False),
)
"""Every term of the model, in the order of the energy vector."""

NAMES: tuple[str, ...] = tuple(t.name for t in TERMS)
"""The term names, in registry order."""


def active_terms(scene) -> tuple[str, ...]:
    """The names of the terms a (validated) scene uses, in registry order."""
    return tuple(t.name for t in TERMS if t.active(scene))


def index(name: str) -> int:
    """The position of term `name` in TERMS: its entry in the energy vector and in `Yarn.active`."""
    return NAMES.index(name)


def active_mask(scene) -> np.ndarray:
    """Which terms a (validated) scene uses, (len(TERMS),) bool in registry order
    (`Yarn.active`)."""
    return np.array([t.active(scene) for t in TERMS], dtype=np.bool_)


def energy_records(scene, values: dict) -> dict[str, float]:
    """{`Term.dataset`: its energy [J]} of every term `scene` has that reports one, from
    `values` {term name: energy [J]} (a model's energy vector by name)."""
    return {t.dataset: float(values[t.name]) for t in TERMS if t.dataset and t.active(scene)}
