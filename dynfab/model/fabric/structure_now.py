"""What a fabric's and a specimen's model share: the structure they have now, its term set
(`dynfab.model.terms.kinematics.terms_of`: its energies, its Hessian and their pattern) and,
where the crossings slide, the crossings still in it as yarn ends leave them (docs/model.md
11.13).

A model holds the structure the scene made (`woven_structure`, every crossing in it) and the
structure now (`structure`), from which each crossing a free yarn end has passed was taken out
at the step it left (`dynfab.model.builders.sliding.leaving`, `without_crossings`);
`tie_crossing` names the scene's crossing of each tie now. A step's record holds every
crossing of the scene (`per_tie`), with the slide of each yarn's material through it from the
as-woven crossing (`slip`, (C, 2) [m]: what the crossing's slots hold), its material
coordinates (`material`, (C, 2) [m]: the woven ones plus the slides) and which crossings are
still there (`crossing_present`, (C,)); a resumed run replays the departures from those
columns (`replay_departures`), as the uninterrupted run made them.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse

from dynfab.errors import UserError
from dynfab.model.builders.sliding import leaving, without_crossings, woven_material
from dynfab.model.fabric import contact
from dynfab.model.structure import Structure
from dynfab.model.structure import sliding as slides
from dynfab.model.terms import registry
from dynfab.model.terms.kinematics import terms_of, woven_state

SLIDING_HISTORY = ("crossing_present", "slip")
"""The step datasets of the whole path a model whose crossings slide needs to resume."""


class StructureNow:
    """Mixin: `woven_structure`, `structure` and `tie_crossing` (module docstring), what
    the structure's term set gives a model, and its records' crossing fields in the file's
    layout; the model gives `scene` and `record_layout` (`dynfab.model.record_layout`) and
    calls `_start_structures` once it has made its structure."""

    structure: Structure

    def _start_structures(self) -> None:
        self.woven_structure = self.structure
        """The structure as the scene made it, every crossing in it."""
        self._set_structure(self.woven_structure, np.arange(self.woven_structure.tie_a.size))

    def _set_structure(self, structure: Structure, tie_crossing: np.ndarray) -> None:
        self.structure, self.tie_crossing = structure, tie_crossing

    @property
    def slides(self) -> bool:
        """The crossings slide along the yarns (docs/model.md 11.13)."""
        return slides(self.woven_structure)

    @property
    def terms(self):
        """The structure's term set (`dynfab.model.terms.kinematics.terms_of`)."""
        return terms_of(self.structure)

    @property
    def pattern(self):
        """The order of the Hessian's entries and its unknowns (the term set's `pattern_of`):
        what the sparse certificate reads (`dynfab.solvers.certificate.certify_patch`)."""
        return self.terms.pattern_of(self.structure)

    def hessian(self, pos, anchors, limit, secant: float = 0.0) -> scipy.sparse.csc_matrix:
        """The Hessian on the unknowns, F_T frozen (the term set's `sparse_hessian`)."""
        return self.terms.sparse_hessian(self.structure, pos, anchors, limit, secant)

    def energies(self, pos, P, anchors, limit) -> np.ndarray:
        """Each term's energy [J] (the term set's `energy_vector`, its TERMS)."""
        return self.terms.energy_vector(self.structure, pos, P, anchors, limit)

    def energy_records(self, pos, P, anchors, limit) -> dict[str, float]:
        """{`energy/<term>`: its energy [J]} of every term the scene reports
        (`dynfab.model.terms.registry.energy_records` of `energies`)."""
        values = dict(zip(self.terms.TERMS, self.energies(pos, P, anchors, limit)))
        return registry.energy_records(self.scene, values)

    def contact_forces(self, pos) -> np.ndarray:
        """R (T,) [N] of every tie at `pos` (`dynfab.model.fabric.contact.forces`)."""
        out = np.zeros(self.structure.tie_a.size)
        contact.forces(pos, self.structure, out)
        return out

    def return_map(self, pos, anchors, limit) -> tuple[np.ndarray, np.ndarray, float]:
        """The friction anchors' return map at a step's end (the term set's `return_map`, the
        anchors mapped in place, F_T = `limit`): (sliding (T,), friction force (T, dim) [N], the
        energy it dissipated [J]); nothing moves without friction."""
        f = self.structure
        sliding = np.zeros(f.tie_a.size, np.bool_)
        friction_force = np.zeros((f.tie_a.size, f.rest_position.shape[1]))
        lost = 0.0
        if f.has_friction:
            lost = self.terms.return_map(pos, anchors, f, limit, sliding, friction_force)
        return sliding, friction_force, lost

    def friction_limits(self, pos) -> np.ndarray:
        """F_T (T,) [N] at `pos` (`dynfab.model.fabric.contact.friction_limits`)."""
        return contact.friction_limits(pos, self.structure)

    @property
    def sliding_history(self) -> tuple:
        """`SLIDING_HISTORY` where the crossings slide, else nothing."""
        return SLIDING_HISTORY if self.slides else ()

    def per_tie(self, values, fill=0.0) -> np.ndarray:
        """Per-tie `values` (T, ...) as the scene's crossings (C, ...): a crossing a yarn end
        has left holds `fill`."""
        values = np.asarray(values)
        out = np.full((self.woven_structure.tie_a.size, *values.shape[1:]), fill, values.dtype)
        out[self.tie_crossing] = values
        return out

    def per_crossing(self, values, fill=0.0) -> np.ndarray:
        """Per-tie `values` (T, ...) as the result file lays out the scene's crossings
        (`per_tie`, then the model's `record_layout`)."""
        return self.record_layout.per_crossing(self.per_tie(values, fill))

    def crossing_records(self, R, limit, sliding, friction_force, anchors) -> dict:
        """A record's crossing fields in the file's layout (`per_crossing`): contact_force R,
        friction_limit F_T [N], sliding, friction_force [N] and anchors of each tie; a crossing
        a yarn end has left holds 0, False and NaN anchors."""
        view = self.per_crossing
        return {"contact_force": view(R), "friction_limit": view(np.asarray(limit, float)),
                "sliding": view(sliding, False), "friction_force": view(friction_force),
                "anchors": view(anchors, np.nan)}

    def with_slides(self, positions, slides) -> np.ndarray:
        """The dofs of the structure now from the physical `positions` (n, dim) and the scene's
        crossings' slides `slides` (C, 2) (a record's `slip`), in their slots."""
        dofs = np.array(positions, float)
        dofs.reshape(-1)[self.structure.tie_material] = \
            np.asarray(slides, float).reshape(-1, 2)[self.tie_crossing]
        return dofs

    def record_slides(self, dofs, record: dict) -> tuple[np.ndarray, list[int]]:
        """Where the crossings slide, a step's end: its slides and material coordinates into
        `record` (in the file's layout of the crossings), then the crossings a yarn end has
        passed taken out of the structure (`leave`) and `crossing_present` after that.
        Returns (the dofs in the structure now, the ties taken out, as indices of the
        structure before)."""
        f = self.structure
        slides = self.per_tie(np.asarray(dofs).reshape(-1)[f.tie_material], np.nan)
        view = self.record_layout.per_crossing
        record["slip"] = view(slides)
        record["material"] = view(woven_material(self.woven_structure) + slides)
        departures = leaving(f, dofs)
        gone = sorted({d.tie for d in departures})
        if departures:
            dofs = self.leave(departures, dofs)
        record["crossing_present"] = self.per_crossing(np.ones(self.tie_crossing.size, bool),
                                                       False)
        return dofs, gone

    def resumed(self, dofs, anchors, last: dict, history: dict) -> tuple[np.ndarray, np.ndarray]:
        """(dofs, anchors) of the state a finished step left, from its record `last`'s
        physical positions `dofs` (n, dim) and anchors (C, k) of every crossing: where the
        crossings slide, the structure after the departures of `history`
        (`replay_departures`), the crossings' slides (`last`'s `slip`) in their slots and
        the anchors of the ties still there; as given otherwise."""
        if self.slides:
            self.replay_departures(history)
            dofs = self.with_slides(dofs, last["slip"])
            anchors = anchors[self.tie_crossing]
        return dofs, anchors

    def replay_departures(self, history: dict) -> None:
        """The structure after the finished steps of `history` (its `crossing_present` and
        `slip` columns): each crossing a yarn end left taken out at the step it left, at that
        step's slides (`leave`), as the uninterrupted run did."""
        self._set_structure(self.woven_structure, np.arange(self.woven_structure.tie_a.size))
        present = np.asarray(history["crossing_present"], bool)
        slides = np.asarray(history["slip"], float)
        for step in range(present.shape[0]):
            gone = ~present[step].ravel()[self.tie_crossing]
            if gone.any():
                dofs = self.with_slides(woven_state(self.structure), slides[step])
                departures = leaving(self.structure, dofs)
                if sorted({d.tie for d in departures}) != list(np.flatnonzero(gone)):
                    raise UserError(f"step {step + 1} of the file: the crossings it left are not "
                                    "those its slides leave (a file of another "
                                    "scene or version); run it again without --resume")
                self.leave(departures, dofs)

    def leave(self, departures: list, dofs) -> np.ndarray:
        """Take the crossings yarn ends have passed out of the structure at `dofs`
        (`dynfab.model.builders.sliding.without_crossings`); returns the dofs of the new
        structure."""
        structure, dofs = without_crossings(self.structure, departures, dofs)
        ties = sorted({d.tie for d in departures})
        self._set_structure(structure, np.delete(self.tie_crossing, ties))
        return dofs
