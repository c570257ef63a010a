"""What every relaxation of one fabric patch on one device holds, and how it is driven
(docs/model.md sections 5, 10).

`PatchRelaxation` is the base of `fabric_explicit.FabricExplicit` and
`fabric_semi_implicit.FabricSemiImplicit`: the patch's arrays uploaded once
(`fabric_arrays.upload`), the Gershgorin masses at the fictitious time step, the velocity,
force, contact-force and friction-force arrays the kernels update in place; `relax`
(start at rest from given positions under given nodal forces, the friction anchors held,
then the subclass's `_run` in its layout) and `return_map` (the anchors' radial return,
docs/model.md section 4, one thread per crossing). `stop_test` is both relaxation kernels'
test, at the top of every time step, of whether the relaxation ends.

Progress within a relaxation: the persistent layouts run their time loop inside one thread,
and a launch cannot be watched or interrupted (Ctrl-C) while it runs, so they launch a
bounded chunk of time steps at a time (`chunks`), each launch continuing the last one's time
loop with the same bits (what the loop carries between steps is kept in device arrays). The
chunks are sized to take about CHUNK_SECONDS each, from the time the last one took; after
each, `report(time steps, residual [N])` is called, if set. The per-step layouts, whose time
loop is in Python, call it at most every CHUNK_SECONDS.
"""

import functools
import time

import numpy as np
import warp as wp

from dynfab.kernels import fabric_arrays, fabric_forces, status
from dynfab.kernels.precision import VECTORS, numpy_dtype


@functools.cache
def stop_test(scalar):
    """The `wp.func` stop(finite, residual, tolerance, step, max_steps) -> status code of a
    relaxation at the top of time step `step`: NON_FINITE where its merits are not `finite`,
    CONVERGED at residual <= tolerance [N], MAX_STEPS once `max_steps` steps are taken, else
    RUNNING (the time loop goes on to its own tests)."""

    @wp.func
    def stop(finite: bool, residual: scalar, tolerance: scalar, step: int, max_steps: int) -> int:
        code = int(status.RUNNING)
        if not finite:
            code = int(status.NON_FINITE)
        elif residual <= tolerance:
            code = int(status.CONVERGED)
        elif step == max_steps:
            code = int(status.MAX_STEPS)
        return code

    return stop


CHUNK_SECONDS = 0.5
"""Wall time [s] a launch of a persistent layout's time loop aims at: the progress line's
update interval and the longest a Ctrl-C waits for the launch to return."""
MAX_CHUNK_GROWTH = 4
"""A chunk is at most this many times the last one (the time per step can change)."""


class PatchRelaxation:
    """A patch's device arrays and the relax / return_map interface; subclasses give `_run`."""

    has_friction: bool = True
    """Whether the kernels are built with the friction terms (the return map's variant)."""
    report = None
    """Called as report(time steps, residual [N]) within a relaxation (module docstring), or
    None."""
    first_chunk: int = 1000
    """Time steps of a persistent layout's first launch of a relaxation (the explicit one's;
    `FabricSemiImplicit` takes fewer, costlier steps)."""
    chunk_seconds: float = CHUNK_SECONDS
    """Wall time [s] each later launch aims at."""

    def chunks(self, max_steps: int):
        """(first, stop_at) of each launch of a persistent time loop, steps first..stop_at-1,
        the last one's stop_at past max_steps; each chunk sized from the time the one before
        took (at most MAX_CHUNK_GROWTH x it, at least one step). The caller stops iterating
        once a launch ends the relaxation."""
        first, size = 0, max(1, int(self.first_chunk))
        while True:
            stop_at = first + size
            started = time.perf_counter()
            yield first, (stop_at if stop_at <= max_steps else max_steps + 1)
            elapsed = time.perf_counter() - started
            wanted = size * self.chunk_seconds / elapsed if elapsed > 0 else size * MAX_CHUNK_GROWTH
            first, size = stop_at, max(1, min(int(wanted), size * MAX_CHUNK_GROWTH))

    def _report(self, steps: int, residual: float) -> None:
        """Tell `report` where the relaxation stands, if it is set."""
        if self.report is not None:
            self.report(int(steps), float(residual))

    def _report_now(self, steps: int, residual: float) -> None:
        """`_report`, at most every `chunk_seconds` (a per-step layout's time loop)."""
        if self.report is None:
            return
        now = time.perf_counter()
        if now - getattr(self, "_reported", 0.0) >= self.chunk_seconds:
            self._reported = now
            self._report(steps, residual)

    def _allocate(self, arrays: fabric_arrays.PatchArrays, device: str, layout: str, scalar,
                  dt: float) -> None:
        """Upload the patch and allocate the state the kernels update (every field zero)."""
        self.arrays, self.device, self.layout, self.dt = arrays, device, layout, dt
        self.scalar, self.dtype, self.vec = scalar, numpy_dtype(scalar), VECTORS[scalar]
        self.fabric = fabric_arrays.upload(arrays, scalar, device)
        self.mass = self._array(fabric_arrays.gershgorin_masses(arrays, dt), scalar)
        n, crossings = arrays.nodes, arrays.crossings
        self.vel, self.force = (self._array(np.zeros((n, 2)), self.vec) for _ in range(2))
        self.contact = self._array(np.zeros(crossings), scalar)
        self.friction = self._array(np.zeros((crossings, 2)), self.vec)

    def _array(self, values, dtype):
        return wp.array(np.asarray(values, self.dtype), dtype=dtype, device=self.device)

    def relax(self, positions: np.ndarray, external: np.ndarray, tolerance: float,
              max_steps: int, anchors: np.ndarray | None = None):
        """Relax from `positions` (n, 2) [m] at rest under the nodal forces `external` (n, 2)
        [N], the friction anchors `anchors` (C, 2) [m] held (default: at the as-woven
        crossings), until the residual is at most `tolerance` [N] or `max_steps` time steps;
        returns (positions (n, 2) [m], the subclass's outcome)."""
        pos = self._array(positions, self.vec)
        self.vel.zero_()
        load = self._array(external, self.vec)
        if anchors is None:
            anchors = np.zeros((self.arrays.crossings, 2))
        self.anchors = self._array(anchors, self.vec)
        pos, outcome = self._run(pos, load, tolerance, max_steps)
        return pos.numpy().astype(float), outcome

    def _run(self, pos, load, tolerance: float, max_steps: int):
        """(final positions array, outcome) of the relaxation in this solver's layout."""
        raise NotImplementedError

    def return_map(self, positions: np.ndarray, anchors: np.ndarray) -> np.ndarray:
        """The anchors (C, 2) [m] after the radial return map at `positions`
        (docs/model.md sections 4, 10)."""
        updated = self._array(anchors, self.vec)
        wp.launch(fabric_forces.kernels(self.scalar, self.has_friction).return_map,
                  dim=self.arrays.crossings, device=self.device,
                  inputs=[self._array(positions, self.vec), self.fabric, updated])
        return updated.numpy().astype(float)
