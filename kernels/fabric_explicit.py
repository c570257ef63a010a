"""Explicit relaxation of a fabric patch: symplectic Euler; viscous, kinetic or FIRE damping
(docs/model.md sections 5, 10).

    v^{n+1/2} = ((1 - c dt/2) v^{n-1/2} + dt M^-1 f(x^n)) / (1 + c dt/2),   x^{n+1} = x^n + dt v^{n+1/2}

with f from `fabric_forces` (per-crossing contact pass, then per-node gather). Kinetic
damping (Barnes, c = 0): when the kinetic energy of the new half-step velocities falls
below the last one, the peak has just been passed; the positions go back to the
estimated peak x* = x^{n+1} - 3/2 dt v^{n+1/2} + dt^2/2 M^-1 f^n and v = 0. FIRE 2.0:
as `kernels/fire.py` (its constants), the time step relative to the stable one of the
Gershgorin masses (dt / GERSHGORIN_SAFETY). Relaxation
stops when the residual, max |f| over the free dofs, is at or below the tolerance.
With friction (the variants built with it) the anchors stay fixed during a relaxation,
the quasi-static incremental form of docs/model.md section 4; `FabricExplicit.return_map` moves them
after a converged one.

Two layouts (tests/test_fabric_kernels.py checks that they agree: bit for bit with
`order="gather"`, to rounding with the default scatter order):

- "persistent": one thread running the time loop over every node (CPU), a chunk of
  time steps per launch (`fabric_relaxation.PatchRelaxation.chunks`: about half a
  second each, so that progress shows and Ctrl-C is taken; the same bits as one
  launch). A CPU `wp.launch` runs its threads one after another on one core
  and costs 10-45 us from Python, so per-step launches on the CPU pay that cost twice
  per step for no parallelism; the loop inside the kernel pays it once a chunk
  (`python benchmarks/fabric.py` measures both). One thread needs no gather: by default
  it evaluates each term once and scatters it (`fabric_forces.scatter_forces`), 1.5-1.7x
  faster than the per-node gather measured on 4x4 to 64x64 patches (which recomputes every
  segment twice and every bending spring three times; `python benchmarks/fabric.py`).
  Viscous, kinetic and FIRE damping.
- "per_step": per time step, one launch of a thread per crossing (R), then one of a
  thread per node (force gather, residual and update, writing the new positions into a
  second buffer: a node's neighbours read the old ones), the GPU layout. Every thread
  writes only its own slots, no atomics, so runs are bit for bit repeatable (a resume
  from saved positions, velocities and anchors would be too; `relax` starts from rest).
  The residual is read back (max over the per-node maxima, exact in any order) every
  `check_interval` steps. Kinetic damping needs the kinetic energy, a sum over all
  nodes, at every step: each node writes its own 1/2 m v^2, a thread per block of
  ENERGY_BLOCK nodes sums its block in order, one thread sums the blocks in order and
  decides whether the peak has passed, and a thread per node applies the back-step
  (three more launches per step, every sum in a fixed order: deterministic). FIRE, whose
  power and norms are sums at every step too, runs in the persistent layout only.

`default_layout(device)` picks "persistent" on the CPU and "per_step" on a GPU.

The boundary (docs/model.md section 10) is data of the fabric (`fabric_arrays`), the same
kernels for every mode. A tied family's end nodes (a periodic cell's length under force
control) each receive the family's summed force and mass, so they update by the same bits;
the kinetic energy and FIRE's power and norms weight each node by its share (1/n for the n
members of a tied family, 1 otherwise), so that one dof counts once.
"""

import functools
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import warp as wp

from dynfab.kernels import fabric_arrays, fabric_forces, fire as fire_module, status
from dynfab.kernels.configuration import MODULE_OPTIONS
from dynfab.kernels.fabric_relaxation import PatchRelaxation, stop_test
from dynfab.kernels.precision import VECTORS

LAYOUTS = ("persistent", "per_step")
ENERGY_BLOCK = 256
"""Nodes per partial sum of the kinetic energy in the per-step layout."""
DAMPINGS = ("viscous", "kinetic", "fire")


def default_layout(device: str) -> str:
    """"persistent" on the CPU, "per_step" on a CUDA device."""
    return "per_step" if wp.get_device(device).is_cuda else "persistent"


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The per-node update `wp.func` shared by both layouts."""
    vec = VECTORS[scalar]

    @wp.func
    def largest_component(f: vec) -> scalar:
        """max(|f_s|, |f_z|) [N]; NaN propagates (a NaN is never <= anything)."""
        worst = wp.abs(f[0])
        if not wp.abs(f[1]) <= worst:
            worst = wp.abs(f[1])
        return worst

    @wp.func
    def velocity(v: vec, f: vec, mass: scalar, dt: scalar, coefficient: scalar) -> vec:
        """v^{n+1/2} [m/s] of the centred viscous step (c = 0: undamped)."""
        half = scalar(0.5) * coefficient * dt
        return ((scalar(1.0) - half) * v + (dt / mass) * f) / (scalar(1.0) + half)

    return SimpleNamespace(largest_component=largest_component, velocity=velocity)


@functools.cache
def persistent_kernel(scalar, damping: str, order: str = "scatter", has_friction: bool = False):
    """One thread relaxes the whole patch, the time loop inside (layout "persistent").

    `order` "scatter" evaluates each term once and adds it to its nodes
    (`fabric_forces.scatter_forces`, the default: one thread needs no gather); "gather"
    runs the per-step layout's per-crossing and per-node passes as loops, the same
    arithmetic in the same order as the per-step layout (bit-identical to it)."""
    vec = VECTORS[scalar]
    Fabric = fabric_arrays.struct(scalar)
    ops, step_ops = fabric_forces.functions(scalar, has_friction), functions(scalar)
    kinetic = damping == "kinetic"
    fire = damping == "fire"
    gather = order == "gather"
    stable = 1.0 / fabric_arrays.GERSHGORIN_SAFETY  # the stable dt / dt of the masses
    f = fire_module
    stop = stop_test(scalar)

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def relax(fabric: Fabric, mass: wp.array(dtype=scalar), share: wp.array(dtype=scalar),
              external: wp.array(dtype=vec), anchors: wp.array(dtype=vec), dt: scalar, coefficient: scalar, tolerance: scalar,
              max_steps: int, first: int, stop_at: int, carry: wp.array(dtype=scalar),
              counters: wp.array(dtype=wp.int32), pos: wp.array(dtype=vec),
              vel: wp.array(dtype=vec),
              force: wp.array(dtype=vec), contact: wp.array(dtype=scalar),
              friction: wp.array(dtype=vec), outcome: wp.array(dtype=wp.int32),
              residual_out: wp.array(dtype=scalar)):
        """Steps `first`, first + 1, ... until residual <= tolerance or max_steps (outcome =
        (status, steps)), or until step `stop_at` (status RUNNING: a later launch from
        first = stop_at continues with the same bits). What the time loop carries from step
        to step besides the arrays is kept in `carry` (kinetic energy, FIRE's h and alpha)
        and `counters` (FIRE's positive and negative step counts)."""
        nodes = pos.shape[0]
        kinetic_energy = scalar(0.0)
        code = int(status.MAX_STEPS)
        steps = int(first)
        residual = scalar(0.0)
        h = wp.min(dt, scalar(f.DT_START * stable) * dt)  # FIRE's time step and state
        alpha = scalar(f.ALPHA_START)
        positive = int(0)
        negative = int(0)
        if first > 0:  # a continued relaxation
            kinetic_energy = carry[0]
            h = carry[1]
            alpha = carry[2]
            positive = int(counters[0])
            negative = int(counters[1])
        for step in range(first, max_steps + 1):
            if step == stop_at:
                code = int(status.RUNNING)
                break
            if wp.static(gather):
                shift = ops.plane_shift(pos, fabric)
                for c in range(contact.shape[0]):
                    ops.crossing_pass_at(pos, fabric, anchors, contact, friction, c, shift)
                for i in range(nodes):
                    force[i] = ops.node_force(i, pos, fabric, contact, friction, external)
            else:
                ops.scatter_forces(pos, fabric, anchors, contact, friction, external, force)
            residual = scalar(0.0)
            for i in range(nodes):
                worst = step_ops.largest_component(force[i])
                if not worst <= residual:
                    residual = worst
            code = stop(wp.isfinite(residual), residual, tolerance, step, max_steps)
            if code != int(status.RUNNING):
                break
            if wp.static(fire):  # FIRE 2.0 as kernels/fire.py, dt relative to the masses' dt
                power = scalar(0.0)
                for i in range(nodes):
                    power += share[i] * wp.dot(force[i], vel[i])
                if power > scalar(0.0):
                    positive += 1
                    negative = 0
                    if positive > f.DELAY_STEPS:
                        h = wp.min(h * scalar(f.DT_GROWTH), scalar(f.DT_MAX * stable) * dt)
                        alpha = alpha * scalar(f.ALPHA_SHRINK)
                else:
                    positive = 0
                    negative += 1
                    if negative > f.MAX_NEGATIVE_STEPS:
                        code = int(status.STALLED)
                        break
                    if step >= f.DELAY_STEPS:
                        if h * scalar(f.DT_SHRINK) >= scalar(f.DT_MIN * stable) * dt:
                            h = h * scalar(f.DT_SHRINK)
                        alpha = scalar(f.ALPHA_START)
                    for i in range(nodes):
                        pos[i] = pos[i] - (scalar(0.5) * h) * vel[i]
                        vel[i] = vec(scalar(0.0), scalar(0.0))
                speed2 = scalar(0.0)
                force2 = scalar(0.0)
                for i in range(nodes):
                    v = vel[i] + (h / mass[i]) * force[i]
                    vel[i] = v
                    speed2 += share[i] * wp.dot(v, v)
                    force2 += share[i] * wp.dot(force[i], force[i])
                mixing = scalar(0.0)
                if force2 > scalar(0.0):
                    mixing = alpha * wp.sqrt(speed2 / force2)
                for i in range(nodes):
                    v = (scalar(1.0) - alpha) * vel[i] + mixing * force[i]
                    vel[i] = v
                    pos[i] = pos[i] + h * v
            else:
                energy = scalar(0.0)
                for i in range(nodes):
                    v = step_ops.velocity(vel[i], force[i], mass[i], dt, coefficient)
                    vel[i] = v
                    pos[i] = pos[i] + dt * v
                    energy += scalar(0.5) * (mass[i] * share[i]) * wp.dot(v, v)
                if wp.static(kinetic):
                    if energy < kinetic_energy:
                        for i in range(nodes):
                            back = scalar(-1.5) * dt * vel[i] + (scalar(0.5) * dt * dt / mass[i]) * force[i]
                            pos[i] = pos[i] + back
                            vel[i] = vec(scalar(0.0), scalar(0.0))
                        energy = scalar(0.0)
                    kinetic_energy = energy
            steps = step + 1
        outcome[0] = code
        outcome[1] = steps
        residual_out[0] = residual
        carry[0] = kinetic_energy
        carry[1] = h
        carry[2] = alpha
        counters[0] = wp.int32(positive)
        counters[1] = wp.int32(negative)

    return relax


@functools.cache
def per_step_kernel(scalar, has_friction: bool = False):
    """One thread per node: gather the force, keep the residual, update (layout "per_step")."""
    vec = VECTORS[scalar]
    Fabric = fabric_arrays.struct(scalar)
    ops, step_ops = fabric_forces.functions(scalar, has_friction), functions(scalar)

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def node_step(fabric: Fabric, mass: wp.array(dtype=scalar), share: wp.array(dtype=scalar),
                  external: wp.array(dtype=vec),
                  dt: scalar, coefficient: scalar, contact: wp.array(dtype=scalar),
                  friction: wp.array(dtype=vec),
                  pos: wp.array(dtype=vec), vel: wp.array(dtype=vec), force: wp.array(dtype=vec),
                  node_residual: wp.array(dtype=scalar), pos_out: wp.array(dtype=vec),
                  node_energy: wp.array(dtype=scalar)):
        """force and node_residual [N] at pos; v, pos_out = pos + dt v [m], 1/2 m v^2 [J]."""
        i = wp.tid()
        f = ops.node_force(i, pos, fabric, contact, friction, external)
        force[i] = f
        node_residual[i] = step_ops.largest_component(f)
        v = step_ops.velocity(vel[i], f, mass[i], dt, coefficient)
        vel[i] = v
        pos_out[i] = pos[i] + dt * v
        node_energy[i] = scalar(0.5) * (mass[i] * share[i]) * wp.dot(v, v)

    return node_step


@functools.cache
def kinetic_kernels(scalar) -> SimpleNamespace:
    """The per-step layout's kinetic damping: block sums, the peak test, the back-step."""
    vec = VECTORS[scalar]

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def block_sums(node_energy: wp.array(dtype=scalar), partial: wp.array(dtype=scalar)):
        """partial[b] = sum of node_energy over block b [J], in node order."""
        b = wp.tid()
        total = scalar(0.0)
        for i in range(b * ENERGY_BLOCK, wp.min((b + 1) * ENERGY_BLOCK, node_energy.shape[0])):
            total += node_energy[i]
        partial[b] = total

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def peak_test(partial: wp.array(dtype=scalar), kinetic: wp.array(dtype=scalar)):
        """kinetic = (last energy [J], 1 if the peak has just passed): one thread."""
        total = scalar(0.0)
        for b in range(partial.shape[0]):
            total += partial[b]
        if total < kinetic[0]:
            kinetic[0] = scalar(0.0)
            kinetic[1] = scalar(1.0)
        else:
            kinetic[0] = total
            kinetic[1] = scalar(0.0)

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def back_step(kinetic: wp.array(dtype=scalar), mass: wp.array(dtype=scalar),
                  force: wp.array(dtype=vec), dt: scalar, vel: wp.array(dtype=vec),
                  pos_out: wp.array(dtype=vec)):
        """At a peak: x* = x - 3/2 dt v + dt^2/2 M^-1 f and v = 0 (node i)."""
        i = wp.tid()
        if kinetic[1] != scalar(0.0):
            pos_out[i] = pos_out[i] + (scalar(-1.5) * dt * vel[i]
                                       + (scalar(0.5) * dt * dt / mass[i]) * force[i])
            vel[i] = vec(scalar(0.0), scalar(0.0))

    return SimpleNamespace(block_sums=block_sums, peak_test=peak_test, back_step=back_step)


@dataclass
class Outcome:
    """What a relaxation reached."""

    status: int
    """A `dynfab.kernels.status` code: CONVERGED, MAX_STEPS or NON_FINITE."""
    steps: int
    """Time steps taken."""
    residual: float
    """max |f| over the free dofs at the final positions [N]."""


class FabricExplicit(PatchRelaxation):
    """Explicit relaxation of one patch on one device (docs/model.md sections 5, 10)."""

    def __init__(self, arrays: fabric_arrays.PatchArrays, *, device: str = "cpu",
                 layout: str | None = None, damping: str = "kinetic", coefficient: float = 0.0,
                 dt: float = 1.0, scalar=wp.float64, check_interval: int = 16,
                 order: str = "scatter", friction: bool | None = None):
        if layout is None:
            layout = default_layout(device)
        if layout not in LAYOUTS or damping not in DAMPINGS:
            raise ValueError(f"layout {layout!r} or damping {damping!r} unknown")
        if layout == "per_step" and damping == "fire":
            raise ValueError("FIRE runs in the persistent layout only")
        self._allocate(arrays, device, layout, scalar, dt)
        self.damping = damping
        self.coefficient = coefficient if damping == "viscous" else 0.0
        self.check_interval, self.order = check_interval, order
        self.has_friction = bool(arrays.friction_law[3] > 0.0) if friction is None else friction
        self.share = self._array(fabric_arrays.energy_shares(arrays), scalar)

    def _run(self, pos, load, tolerance, max_steps):
        if self.layout == "persistent":
            return pos, self._persistent(pos, load, tolerance, max_steps)
        return self._per_step(pos, load, tolerance, max_steps)

    def _persistent(self, pos, load, tolerance, max_steps) -> Outcome:
        """The time loop in the kernel, launched for a bounded chunk of steps at a time
        (`PatchRelaxation.chunks`), the same bits as one launch."""
        code = wp.zeros(2, dtype=wp.int32, device=self.device)
        residual = wp.zeros(1, dtype=self.scalar, device=self.device)
        carry = wp.zeros(3, dtype=self.scalar, device=self.device)
        counters = wp.zeros(2, dtype=wp.int32, device=self.device)
        kernel = persistent_kernel(self.scalar, self.damping, self.order, self.has_friction)
        for first, stop_at in self.chunks(max_steps):
            wp.launch(kernel, dim=1, device=self.device,
                      inputs=[self.fabric, self.mass, self.share, load, self.anchors,
                              self.scalar(self.dt), self.scalar(self.coefficient),
                              self.scalar(tolerance), int(max_steps), first, stop_at, carry,
                              counters, pos, self.vel, self.force, self.contact, self.friction,
                              code, residual])
            status_code, steps = (int(v) for v in code.numpy())
            outcome = Outcome(status_code, steps, float(residual.numpy()[0]))
            if status_code != status.RUNNING:
                return outcome
            self._report(steps, outcome.residual)
        raise AssertionError("the last chunk ends at max_steps")

    def _per_step(self, pos, load, tolerance, max_steps):
        passes = fabric_forces.kernels(self.scalar, self.has_friction)
        step_kernel = per_step_kernel(self.scalar, self.has_friction)
        other = wp.empty_like(pos)
        node_residual = wp.zeros(self.arrays.nodes, dtype=self.scalar, device=self.device)
        node_energy = wp.zeros(self.arrays.nodes, dtype=self.scalar, device=self.device)
        blocks = (self.arrays.nodes + ENERGY_BLOCK - 1) // ENERGY_BLOCK
        partial = wp.zeros(blocks, dtype=self.scalar, device=self.device)
        kinetic = wp.zeros(2, dtype=self.scalar, device=self.device)
        damping = kinetic_kernels(self.scalar) if self.damping == "kinetic" else None
        dt, c = self.scalar(self.dt), self.scalar(self.coefficient)
        step = 0
        while True:  # forces and residual at pos, and the move to `other`, in one pass
            wp.launch(passes.crossing_pass, dim=self.arrays.crossings, device=self.device,
                      inputs=[pos, self.fabric, self.anchors, self.contact, self.friction])
            wp.launch(step_kernel, dim=self.arrays.nodes, device=self.device,
                      inputs=[self.fabric, self.mass, self.share, load, dt, c, self.contact, self.friction, pos,
                              self.vel, self.force, node_residual, other, node_energy])
            if step == max_steps or step % self.check_interval == 0:
                residual = float(np.max(node_residual.numpy(), initial=0.0))
                if not np.isfinite(residual):
                    return pos, Outcome(status.NON_FINITE, step, residual)
                if residual <= tolerance:
                    return pos, Outcome(status.CONVERGED, step, residual)
                if step == max_steps:
                    return pos, Outcome(status.MAX_STEPS, step, residual)
                self._report_now(step, residual)
            if damping is not None:
                self._kinetic_damping(damping, node_energy, partial, kinetic, dt, other)
            pos, other = other, pos
            step += 1

    def _kinetic_damping(self, kernels, node_energy, partial, kinetic, dt, pos_out):
        """The peak test on the step's kinetic energy, summed in a fixed order, and the back-step."""
        wp.launch(kernels.block_sums, dim=partial.shape[0], device=self.device,
                  inputs=[node_energy, partial])
        wp.launch(kernels.peak_test, dim=1, device=self.device, inputs=[partial, kinetic])
        wp.launch(kernels.back_step, dim=self.arrays.nodes, device=self.device,
                  inputs=[kinetic, self.mass, self.force, dt, self.vel, pos_out])
