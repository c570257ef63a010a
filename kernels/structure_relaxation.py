"""Dynamic relaxation and transient dynamics of any structure with the Warp kernels: the host
side (docs/model.md sections 4, 5, 10; "The dynamic solver (decisions)").

`StructureRelaxation(structure, ...)` lays a `dynfab.model.structure.Structure` out
(`structure_arrays`), uploads it once and drives the kernels of one method:

- `relax(positions, loads, anchors, tolerance, max_steps)`: a quasi-static load step from rest,
  the anchors held, the end loads given per chain or per dof (gravity is the structure's own),
  each group of chains relaxed until its largest free force component is within the
  tolerance (or a failure: `dynfab.kernels.status`); returns the positions and an `Outcome`
  per group;
- `return_map(positions, anchors)`: the anchors after the radial return map and the energy
  each tie dissipated (docs/model.md section 4);
- `tie_forces`, `forces`, `internal_force`, `energies`: contact and friction forces, the
  force on the free dofs, the reaction-side internal force (end dofs unmasked, no external
  load), each unit's energy;
- `transient(positions, anchors, path, duration, output_interval)`: frames of a transient in
  physical time (the load ramped through `path`, one row per load family).

Methods: "explicit" (damping "viscous" with a given c or, c None, the adaptive c; "kinetic";
"fire") and "semi_implicit" (`structure_semi_implicit`; a viscous c only if given). Masses
"fictitious" (Gershgorin, dt = 1 s or the dt given) or "physical" (dt = safety x the
Gershgorin bound, or the dt given). Layouts: "grouped" (the CPU's: a thread per group, the
time loop in the kernel, a chunk of steps per launch; the groups split into contiguous ranges
launched at once on up to `cores` cores, each range a launch of its own, bit-identical
whatever the split) and "node_parallel" (the GPU's: a launch per stage, the time loop here,
the statuses read back every `check_interval` steps). The grouped layout evaluates forces in
"scatter" order (each term once) or "gather" order (bit-identical to node_parallel). A
relaxation runs `chunk` steps in its first launch (the node-parallel layout: before it calls
`progress`), then chunks sized to take about `chunk_seconds` each, so that progress is shown
and Ctrl-C taken within a step (the bits do not depend on the chunks).
"""

from __future__ import annotations

import concurrent.futures
import os
import threading
import time
from dataclasses import dataclass

import numpy as np
import warp as wp

from dynfab.errors import SolverError
from dynfab.kernels import status, structure_arrays, structure_explicit, structure_forces
from dynfab.kernels import structure_passes
from dynfab.kernels import structure_semi_implicit as semi
from dynfab.kernels import structure_settings, structure_state, structure_transient
from dynfab.kernels import structure_variants
from dynfab.kernels.precision import KINEMATICS_OF_DIM, SCALARS, numpy_dtype, vector
from dynfab.model.fabric.sliding import STRETCHES, has_stretches, state_anchors
from dynfab.model.fabric.sliding import with_stretches
from dynfab.model.structure import Structure, dim, sliding
from dynfab.model.terms import kinematics

METHODS = ("explicit", "semi_implicit")
LAYOUTS = ("grouped", "node_parallel")
MASSES = ("fictitious", "physical")
STEPS_PER_LAUNCH = 2000
"""Time steps of a relaxation's first launch, explicit (the chunk Python regains control
after: progress, Ctrl-C); later chunks are sized to take about CHUNK_SECONDS."""
SEMI_IMPLICIT_CHUNK = 16
"""Time steps of a semi-implicit relaxation's first launch (a step of a large patch is many CG
iterations)."""
CHUNK_SECONDS = 0.5
"""Wall time a relaxation's launch is sized to take after the first [s] (`relax`)."""
MAX_CHUNK_GROWTH = 4
"""A chunk is at most this many times the last one (the time per step can change)."""
SAFETY = 0.9
"""dt / the Gershgorin stable time step by default [-] (docs/model.md section 5)."""
RUNNING_FOREVER = 2 ** 31 - 1
"""max_steps of a transient: it ends by time, not by a step count."""


def kernel_kinematics(structure: Structure) -> str:
    """The kernels' kinematics of `structure` (`dynfab.kernels.precision.KINEMATICS`): planar or
    spatial by its coordinates, "_sliding" after it where its crossings slide."""
    name = KINEMATICS_OF_DIM[dim(structure)]
    return f"{name}_sliding" if sliding(structure) else name


@dataclass
class Outcome:
    """What a relaxation reached, per group (`StructureArrays` groups)."""

    status: np.ndarray
    """(G,) `dynfab.kernels.status` codes."""
    steps: np.ndarray
    """(G,) time steps taken (undone ones included)."""
    residual: np.ndarray
    """(G,) the largest free force component at the final positions [N]."""
    tolerance: np.ndarray
    """(G,) the residual each group was to reach [N]."""
    cg_iterations: np.ndarray
    """(G,) CG iterations (semi-implicit; 0 otherwise)."""
    rejected: np.ndarray
    """(G,) undone steps (semi-implicit)."""
    shortened: np.ndarray
    """(G,) steps accepted at a fraction of their length (semi-implicit)."""

    @property
    def succeeded(self) -> bool:
        """Every group converged or reached its rounding floor."""
        return bool(np.isin(self.status, status.SUCCESS).all())


def default_layout(device: str) -> str:
    """"grouped" on the CPU, "node_parallel" on a CUDA device."""
    return "node_parallel" if wp.get_device(device).is_cuda else "grouped"


def available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


_POOL: concurrent.futures.ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def _worker_pool() -> concurrent.futures.ThreadPoolExecutor:
    """The process's pool of launch threads, made on first use."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = concurrent.futures.ThreadPoolExecutor(
                max_workers=max(1, available_cores() - 1), thread_name_prefix="dynfab-groups")
        return _POOL


class StructureRelaxation:
    """One structure's kernels on one device (module docstring).

    The keywords are the dynamic options a run chooses ([dynamic]: precision, method, damping,
    masses, dt, safety), the layout, device and cores, and `friction` / `boundary` to compile
    those terms in whether or not the structure has them (so that tests share one variant).
    Tuning that only tests and benchmarks change is attributes, set after construction:
    `chunk`, `chunk_seconds`, `check_interval` (launch sizes), `cg_tolerance`, `backtracks`,
    `secant`, `direct` (the semi-implicit time step's rule)."""

    def __init__(self, structure: Structure, *, precision: str = "float64",
                 method: str = "explicit", damping: str | None = "kinetic",
                 damping_coefficient: float | None = None, masses: str = "fictitious",
                 dt: float | None = None, safety: float = SAFETY, layout: str | None = None,
                 order: str = "scatter", device: str = "cpu",
                 friction: bool | None = None, boundary: bool | None = None,
                 cores: int | None = 1):
        layout = default_layout(device) if layout is None else layout
        if method not in METHODS or layout not in LAYOUTS or masses not in MASSES \
                or order not in structure_explicit.ORDERS or precision not in SCALARS:
            raise ValueError(f"method {method!r}, layout {layout!r}, masses {masses!r}, order "
                             f"{order!r} or precision {precision!r} unknown")
        if method == "explicit" and damping not in structure_settings.DAMPINGS:
            raise ValueError(f"damping {damping!r} unknown; one of {structure_settings.DAMPINGS}")
        self.arrays = arrays = structure_arrays.build(structure)
        self.structure, self.dim = structure, arrays.dim
        self.kinematics = kernel_kinematics(structure)
        if arrays.sliding:  # the slides' forces are gathered (planar_terms.material_force)
            order = "gather"
        elements = structure_forces.KINDS[self.kinematics]
        self.rows_from_host = elements.ROWS_FROM_HOST
        self.method, self.layout, self.order, self.device = method, layout, order, device
        self.damping = damping if method == "explicit" else None
        self.coefficient = damping_coefficient
        self.masses, self.dt, self.safety = masses, dt, safety
        self.cg_tolerance = semi.CG_TOLERANCE
        """The CG's relative residual per semi-implicit time step."""
        self.backtracks = semi.MAX_BACKTRACKS
        """Line-search halvings of a semi-implicit time step before it is undone (0: halving
        dt instead)."""
        self.secant = arrays.plane_nodes.size > 0
        """The semi-implicit tangent's sliding ties on their secant (moving planes: on)."""
        self.direct = True
        """The semi-implicit system solved by the bands' factors where they are the whole
        tangent (no CG)."""
        self.chunk = STEPS_PER_LAUNCH if method == "explicit" else SEMI_IMPLICIT_CHUNK
        """The first launch's time steps (a transient's: every launch's)."""
        self.check_interval = 16
        """The node-parallel layout's time steps between two reads of the statuses."""
        self.chunk_seconds = CHUNK_SECONDS
        """The wall time later launches are sized to [s] (`relax`); None: every launch
        `chunk` steps."""
        self.rows_floor = None
        """Where the host gives the masses' rows, the least rows and diagonals (n,) [N/m] a
        relaxation takes (`stiffen`); None: the rows at its start alone."""
        self.friction = arrays.has_friction if friction is None else friction
        self.boundary = arrays.has_boundary if boundary is None else boundary
        if arrays.has_friction and not self.friction or arrays.has_boundary and not self.boundary:
            raise ValueError("the structure has friction or boundary couplings the variant lacks")
        if self.boundary and not elements.BOUNDARY:
            raise ValueError(f"{self.kinematics} kernels without moving planes, wraps or tied dofs")
        self.scalar = SCALARS[precision]
        self.dtype, self.vec = numpy_dtype(self.scalar), vector(self.scalar, self.dim)
        self.data = structure_arrays.upload(arrays, self.scalar, device)
        self.state = structure_state.allocate(arrays, self.scalar, device,
                                              method == "semi_implicit", self.rows_from_host)
        self._scratch = None
        self._outs = {}
        self._host = wp.get_device(device).is_cpu
        self._reaction_data = None
        self._loaded = set()
        self.use_cores(cores)

    # ------------------------------------------------------------------ layout

    def use_cores(self, cores: int | None = None) -> None:
        """Launch the grouped layout's groups on up to `cores` CPU cores (None: every core
        this process may run on), in contiguous ranges of nearly equal size."""
        groups = self.arrays.groups
        self.cores = available_cores() if cores is None else max(1, int(cores))
        splits = self.layout == "grouped" and str(self.device).startswith("cpu") and groups > 1
        count = min(self.cores, groups) if splits else 1
        bounds = np.linspace(0, groups, count + 1).round().astype(int)
        self.ranges = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]

    @property
    def variant(self):
        """The `structure_variants.Variant` of this relaxation's kernel (its method and layout)."""
        return structure_variants.describe(self.method, self.layout, self.scalar, self.friction,
                                           self.boundary,
                                           self.order if self.layout == "grouped" else None,
                                           self.kinematics)

    def _kernels(self):
        key = (self.scalar, self.friction, self.boundary)
        if self.method == "explicit":
            if self.layout == "grouped":
                return structure_explicit.grouped_kernel(*key, self.order,
                                                         kinematics=self.kinematics)
            return structure_explicit.stage_kernel(*key, kinematics=self.kinematics)
        if self.layout == "grouped":
            return semi.grouped_kernel(*key, self.order, kinematics=self.kinematics)
        return semi.stage_kernel(*key, kinematics=self.kinematics)

    def _launch_groups(self, kernel, inputs, tail=(), groups=None) -> None:
        """One launch of a grouped kernel per range of groups (`use_cores`), at once, each
        thread given its group offset; `groups` (G,) bool limits them to ranges holding one."""
        ranges = self.ranges
        if groups is not None:
            ranges = [(a, b) for a, b in ranges if groups[a:b].any()]
        if len(ranges) == 1:
            a, b = ranges[0]
            wp.launch(kernel, dim=b - a, inputs=[*inputs, a, *tail], device=self.device)
            return
        if kernel not in self._loaded:  # load (or compile) once, not from two threads at once
            wp.load_module(kernel.module, device=self.device, block_dim=1)
            self._loaded.add(kernel)

        def launch(bounds):
            wp.launch(kernel, dim=bounds[1] - bounds[0], block_dim=1,
                      inputs=[*inputs, bounds[0], *tail], device=self.device)

        pool = _worker_pool()
        futures = [pool.submit(launch, bounds) for bounds in ranges[1:]]
        try:
            launch(ranges[0])
        finally:
            for future in futures:
                future.result()

    def _stage(self, kernel, stage: int, kind_count: int, settings, *extra, data=None) -> None:
        if kind_count:
            data = self.data if data is None else data
            wp.launch(kernel, dim=kind_count, device=self.device,
                      inputs=[data, self.state, settings, *extra[:-1], stage, *extra[-1:]]
                      if extra else [data, self.state, settings, stage])

    def _count(self, kind) -> int:
        """The threads of a stage over `kind`: a node, tie, block, chain, group (every method's
        kinds) or dof (`structure_semi_implicit.DOF`) each."""
        a = self.arrays
        return {0: a.nodes, 1: a.ties, 2: a.blocks, 3: a.chains, 4: a.groups,
                5: a.dim * a.nodes}[kind]

    # ------------------------------------------------------------------ inputs

    def _vectors(self, values):
        values = np.asarray(values, float).reshape(-1, self.dim)
        return wp.array(values.astype(self.dtype), dtype=self.vec, device=self.device)

    def _scalars(self, values):
        values = np.asarray(values, float)
        return wp.array(values.astype(self.dtype), dtype=self.scalar, device=self.device)

    def _set(self, dest, values) -> None:
        """dest (a vector array of the state) = values (n, dim), in this relaxation's scalar: on
        the CPU straight into its memory (no array made per call), on a device through a host
        array."""
        values = np.asarray(values, float).reshape(-1, self.dim)
        if self._host:
            dest.numpy()[...] = values
        else:
            dest.assign(self._vectors(values))

    def node_loads(self, loads) -> np.ndarray:
        """End loads (n, dim) [N] from loads per chain (Y,) (each on its chain's last node along
        the chain) or per dof ((n, dim) or (dim n,)); zeros for None."""
        a = self.arrays
        if loads is None:
            return np.zeros((a.nodes, a.dim))
        loads = np.asarray(loads, float)
        if loads.shape == (a.chains,):
            out = np.zeros((a.nodes, a.dim))
            out[a.chain_start[1:] - 1, 0] = loads
            return out
        return loads.reshape(a.nodes, a.dim).copy()

    def chain_loads(self, values) -> np.ndarray:
        """Loads per chain (Y,) [N or m] from one value per family: value x the load factor."""
        a = self.arrays
        last = a.chain_start[1:] - 1
        factors = a.load_direction[last, 0]
        return np.asarray(values, float)[a.load_family[last]] * factors

    def stiffen(self, anchors, *positions, factor: float = 1.0) -> None:
        """The next relaxations' masses at least `factor` times those of the stiffest tangent
        at each of `positions` and the last floor (`rows_floor`; host rows only: where the
        crossings slide, a step that draws a bay's material through its crossing stiffens the
        bay's segments, EA / L and EI / lbar, past the rows at its start)."""
        rows = [kinematics.stiffest_rows(self.structure, p, anchors) for p in positions]
        rows = [part for part in rows if part is not None]  # None: a bay out of material
        if self.rows_floor is not None:
            rows.append(self.rows_floor)
        self.rows_floor = tuple(factor * np.max(part, axis=0) for part in zip(*rows))

    def as_woven_anchors(self) -> np.ndarray:
        """Anchors at zero slip as woven (`dynfab.model.terms.kinematics.woven_anchors`)."""
        return kinematics.woven_anchors(self.structure)

    def _set_anchors(self, state, positions, anchors) -> np.ndarray:
        """The state's anchors (default `as_woven_anchors`); where the crossings slide, a
        step's (xi_a, xi_b, lambda_a, lambda_b[, phi_anchor]) (T, 4 or 5), or a state's (xi_a,
        xi_b[, phi_anchor]) with the stretches at `positions`
        (`dynfab.model.fabric.sliding.with_stretches`), split into the anchors (xi_a, xi_b[,
        phi_anchor]) and `state.stretch` (lambda_a, lambda_b[, 1]) (docs/model.md 11.13c).
        Returns the anchors whole."""
        anchors = self.as_woven_anchors() if anchors is None else np.asarray(anchors, float)
        if not self.arrays.sliding:
            self._set(state.anchors, anchors[:, :self.dim])
            return anchors
        if not has_stretches(anchors):
            anchors = with_stretches(positions, self.structure, anchors)
        stretch = np.ones((anchors.shape[0], self.dim))
        stretch[:, :2] = anchors[:, STRETCHES]
        self._set(state.stretch, stretch)
        self._set(state.anchors, state_anchors(anchors))
        return anchors

    def _settings(self, **values):
        fictitious = int(self.masses == "fictitious")
        coefficient = self.coefficient
        if coefficient is None:
            coefficient = -1.0 if self.damping == "viscous" else 0.0
        damping = structure_settings.DAMPINGS.index(self.damping) if self.damping else 0
        base = dict(safety=self.safety, fixed_dt=self.dt or 0.0, fictitious=fictitious,
                    damping=damping, damping_coefficient=coefficient,
                    cg_tolerance=self.cg_tolerance,
                    backtracks=self.backtracks, secant=int(self.secant), direct=int(self.direct),
                    chunk=self.chunk)
        base.update(values)
        return structure_settings.fill(self.scalar, **base)

    def _load_state(self, positions, loads, anchors) -> None:
        s = self.state
        anchors = self.as_woven_anchors() if anchors is None else anchors
        self._set(s.position, positions)
        self._set(s.load, self.node_loads(loads))
        anchors = self._set_anchors(s, positions, anchors)
        host = kinematics.stiffest_rows(self.structure, positions, anchors)
        if host is not None and self.rows_floor is not None:
            host = tuple(np.maximum(mine, floor) for mine, floor in zip(host, self.rows_floor))
        if host is not None:  # the Gershgorin rows of the stiffest tangent, from the host
            s.rows.assign(self._scalars(host[0]))
            s.diagonal.assign(self._scalars(host[1]))
        s.velocity.zero_()
        s.previous_force.zero_()
        s.status.fill_(status.RUNNING)

    # ------------------------------------------------------------------ relaxation

    def relax(self, positions, loads=None, anchors=None, *, tolerance: float,
              max_steps: int, relative_tolerance: float = 0.0, progress=None):
        """Relax from `positions` (n, 2) [m] at rest under `loads` (`node_loads`) with the
        `anchors` (T, 2) [m] held (default `as_woven_anchors`) until every group's residual is
        within `tolerance` [N] (with `relative_tolerance` > 0, the default rule of
        `structure_checks`) or it stops otherwise; `progress(self)` after every launch.
        Returns (positions (n, 2) [m], Outcome)."""
        self._load_state(positions, loads, anchors)
        settings = self._settings(tolerance=tolerance, relative_tolerance=relative_tolerance,
                                  max_steps=int(max_steps))
        self._start(settings)
        codes = self.state.status.numpy()
        size = max(1, self.chunk)
        while (codes == status.RUNNING).any():
            settings.chunk = size
            began = time.perf_counter()
            self._advance(settings, codes == status.RUNNING, size)
            codes = self.state.status.numpy()
            if progress is not None:
                progress(self)
            size = self._next_chunk(size, time.perf_counter() - began)
        return self.positions(), self.outcome()

    def _next_chunk(self, size: int, elapsed: float) -> int:
        """The next launch's time steps: sized to take `chunk_seconds` from the time the last
        `size` took (at most MAX_CHUNK_GROWTH x it, at least 1); `size` when chunk_seconds is
        None. Each launch continues the time loop from the state it left: the bits do not
        depend on the chunks."""
        if self.chunk_seconds is None:
            return size
        wanted = size * self.chunk_seconds / elapsed if elapsed > 0 else size * MAX_CHUNK_GROWTH
        return max(1, min(int(wanted), size * MAX_CHUNK_GROWTH))

    def start(self, positions, loads=None, anchors=None) -> None:
        """Only a relaxation's start: forces, masses, time steps (`group_values("dt")`,
        "stable_dt"), tolerances at `positions`."""
        self._load_state(positions, loads, anchors)
        self._start(self._settings(tolerance=0.0, max_steps=1))

    def _start(self, settings) -> None:
        kernel = self._kernels()
        if self.layout == "grouped":
            self._launch_groups(kernel, [self.data, self.state, settings], (1,))
            return
        for stage in structure_explicit.START_STAGES:
            if self.method == "semi_implicit" and stage == structure_explicit.START_DAMPING:
                continue
            self._stage(kernel, stage, self._count(structure_explicit.KINDS[stage]), settings)

    def _advance(self, settings, running: np.ndarray, size: int) -> None:
        """Up to `size` time steps of every running group (settings.chunk = size)."""
        if self.layout == "grouped":
            self._launch_groups(self._kernels(), [self.data, self.state, settings], (0,),
                                groups=running)
        elif self.method == "explicit":
            self._explicit_steps(settings, size)
        else:
            self._semi_steps(settings, size)

    def _explicit_steps(self, settings, size: int) -> None:
        kernel = self._kernels()
        adaptive = self.damping == "viscous" and settings.damping_coefficient < 0.0
        stages = [(stage, self._count(structure_explicit.KINDS[stage]))
                  for stage in structure_explicit.step_stages(self.damping, adaptive)]
        for step in range(size):
            for stage, count in stages:
                self._stage(kernel, stage, count, settings)
            if (step + 1) % self.check_interval == 0 and \
                    not (self.state.status.numpy() == status.RUNNING).any():
                return

    def _semi_steps(self, settings, size: int) -> None:
        kernel = self._kernels()
        counts = {stage: self._count(kind) for stage, kind in semi.KINDS.items()}

        def run(*stages):
            for stage in stages:
                self._stage(kernel, stage, counts[stage], settings)

        def running():
            return self.state.status.numpy() == status.RUNNING

        for _ in range(size):
            if not running().any():
                return
            run(semi.TIE_BLOCKS)
            for _ in range(semi.MAX_REFACTORISATIONS):
                run(semi.BUILD, semi.FACTORED)
                live = running()
                if (self.state.factored.numpy()[live] != 0).all():
                    break
            run(semi.VELOCITY, semi.BOUNDARY, semi.RHS, semi.CG_START, semi.PRECONDITION,
                semi.FIRST_SUM, semi.COPY)
            while True:
                live = running()
                if (self.state.cg.numpy()[live, semi.CG_DONE] != 0).all():
                    break
                run(semi.CG_BOUNDARY, semi.PRODUCT, semi.CURVATURE, semi.STEP_LENGTH,
                    semi.UPDATE, semi.PRECONDITION, semi.NEXT_SUM, semi.DIRECTION)
            run(semi.MOVE, semi.TIES, semi.GATHER, semi.BLOCKS, semi.SEARCH)
            for _ in range(self.backtracks):
                if not (self.state.decision.numpy()[running()] == semi.TRIAL).any():
                    break
                run(semi.TRIAL_MOVE, semi.TIES, semi.GATHER, semi.BLOCKS, semi.SEARCH)
            run(semi.FINISH, semi.RE_TIES, semi.RE_GATHER, semi.RE_BLOCKS, semi.FINISH_GROUP,
                semi.CHECK)

    # ------------------------------------------------------------------ results

    def positions(self) -> np.ndarray:
        """Node positions (n, 2) [m], float64 (where the crossings slide, the dofs: a retired
        tail's tied dofs, held in the kernels, moved as those they are tied to)."""
        out = self.state.position.numpy().astype(np.float64)
        if self.arrays.sliding:
            flat, tie = out.reshape(-1), np.asarray(self.structure.dof_tie)
            start = self.state.start_position.numpy().astype(np.float64).reshape(-1)
            tied = np.flatnonzero(structure_arrays.retired_tails(self.structure))
            flat[tied] += flat[tie[tied]] - start[tie[tied]]
        return out

    def group_values(self, name: str) -> np.ndarray:
        """A per-group (or other) field of the state, as float64 or int (copies): "dt",
        "stable_dt", "residual", "tolerance", "steps", "energy_ratio", "mass", ..."""
        return structure_state.read(self.state, name)

    def outcome(self) -> Outcome:
        read = self.group_values
        return Outcome(status=read("status"), steps=read("steps"), residual=read("residual"),
                       tolerance=read("tolerance"), cg_iterations=read("cg_iterations"),
                       rejected=read("rejected"), shortened=read("shortened"))

    # ------------------------------------------------------------------ passes

    def _passes(self, positions, anchors, loads=None, data=None):
        """A scratch state at `positions` with `anchors` and `loads`, its tie pass done."""
        if self._scratch is None:
            self._scratch = structure_state.allocate(self.arrays, self.scalar, self.device, False,
                                                     self.rows_from_host)
        s = self._scratch
        self._set(s.position, positions)
        self._set_anchors(s, positions, anchors)
        self._set(s.load, self.node_loads(loads))
        self._pass(structure_passes.TIES, self.arrays.ties, data)
        return s

    def _pass(self, which: int, count: int, data=None, out=None):
        kernel = structure_passes.pass_kernel(self.scalar, self.friction, self.boundary,
                                              kinematics=self.kinematics)
        if out is None:  # one per pass, kept: a pass writes every unit's entry
            if which not in self._outs:
                self._outs[which] = wp.zeros(max(count, 1), dtype=self.scalar,
                                             device=self.device)
            out = self._outs[which]
        if count:
            wp.launch(kernel, dim=count, device=self.device,
                      inputs=[self.data if data is None else data, self._scratch, which, out])
        return out

    def tie_forces(self, positions, anchors=None):
        """(R (T,) [N], friction force on the slips (T, 2) [N], F_T (T,) [N]) at `positions`."""
        s = self._passes(positions, anchors)
        return (structure_state.read(s, "contact"), structure_state.read(s, "friction"),
                structure_state.read(s, "limit"))

    def forces(self, positions, loads=None, anchors=None) -> np.ndarray:
        """-dV/dr + the friction forces (n, 2) [N] on the free dofs (a tied family's summed on
        each of its nodes), the gather order's bits."""
        self._passes(positions, anchors, loads)
        self._pass(structure_passes.FORCES, self.arrays.nodes)
        return structure_state.read(self._scratch, "force")

    def internal_force(self, positions, anchors=None) -> np.ndarray:
        """-dV/dr (+ friction) (n, 2) [N] without external loads or gravity, every dof
        unmasked (an end's reaction is minus its in-plane component)."""
        if self._reaction_data is None:
            a = self.arrays
            self._reaction_data = structure_arrays.upload(
                a, self.scalar, self.device, free=np.ones_like(a.free),
                weight=np.zeros_like(a.weight))
        self._passes(positions, anchors, None, self._reaction_data)
        self._pass(structure_passes.FORCES, self.arrays.nodes, self._reaction_data)
        return structure_state.read(self._scratch, "force")

    def energies(self, positions, loads=None, anchors=None):
        """(per node (n,), per tie (T,)) energies [J] (`structure_forces.node_energy`,
        `tie_energy`); their sum is V plus the Huber terms at F_T of the current R."""
        self._passes(positions, anchors, loads)
        nodes = self._pass(structure_passes.NODE_ENERGY, self.arrays.nodes).numpy()
        ties = self._pass(structure_passes.TIE_ENERGY, self.arrays.ties).numpy()
        return nodes[:self.arrays.nodes].astype(float), ties[:self.arrays.ties].astype(float)

    def lateral_energies(self, positions) -> np.ndarray:
        """Each lateral contact's energy (L,) [J] (spatial, docs/model.md section 11.5)."""
        self._passes(positions, None)
        out = self._pass(structure_passes.LATERAL_ENERGY, self.arrays.laterals).numpy()
        return out[:self.arrays.laterals].astype(float)

    def return_map(self, positions, anchors):
        """(anchors (T, 2) [m] after the radial return map at `positions`, the energy each tie
        dissipated (T,) [J]) (docs/model.md sections 4, 10; where the crossings slide the
        step's anchors (T, 4 or 5), their stretches kept, 11.13c)."""
        s = self._passes(positions, anchors)
        lost = self._pass(structure_passes.RETURN_MAP, self.arrays.ties).numpy()
        moved = structure_state.read(s, "anchors")
        if self.arrays.sliding:  # a step's anchors: the stretches after the material ones
            stretch = structure_state.read(s, "stretch")[:, :2]
            moved = np.hstack([moved[:, :2], stretch, moved[:, 2:]])
        return moved, lost[:self.arrays.ties].astype(float)

    # ------------------------------------------------------------------ transient

    def transient(self, positions, anchors, path, duration: float, output_interval: float,
                  resume_from: dict | None = None, progress=None, name=None, driven=None):
        """Frames of a transient from `positions` at rest (docs/model.md section 5): physical
        masses, the viscous c given (default 0), anchors return-mapped every step, the loads
        ramped through `path` (rows, K) [N or m] over `duration` [s]; a frame at t = 0
        (unless resumed) and every `output_interval`, the last at `duration`, the time step
        (at most the Gershgorin dt x safety, or the dt given) shortened to land on each.
        `driven`, (first row (n,), direction (n, dim)) per node, replaces the structure's
        load nodes (`structure_transient`: a chain end's family, a specimen's held nodes);
        None keeps them, one row per load family. `resume_from`, a frame of this run,
        continues from it bit for bit (its positions, velocities, forces and anchors replace
        those at the start, and its per-tie dissipation where it has one). `progress(self)`
        after every launch; `name(g)` names group g in the SolverError of a group that
        stopped (default "group g")."""
        if self.method != "explicit":
            raise ValueError("a transient runs the explicit integrator")
        a = self.arrays
        kernel_key = (self.scalar, self.friction, self.boundary)
        path = np.asarray(path, float)
        path_wp = self._scalars(path.reshape(a.families, -1) if driven is None else path)
        data = self.data
        if driven is not None:
            family, direction = driven
            data = structure_arrays.upload(a, self.scalar, self.device, load_family=family,
                                           load_direction=direction)
        self._load_state(positions, None, anchors)
        self.state.dissipated.zero_()
        coefficient = self.coefficient or 0.0
        base = dict(tolerance=-1.0, max_steps=RUNNING_FOREVER, fictitious=0,
                    damping=structure_settings.VISCOUS, damping_coefficient=coefficient,
                    duration=duration)
        settings = self._settings(**base)
        grouped = self.layout == "grouped"
        kinematics = {"kinematics": self.kinematics}
        kernel = (structure_transient.grouped_kernel(*kernel_key, self.order, **kinematics)
                  if grouped else structure_transient.stage_kernel(*kernel_key, **kinematics))
        if grouped:
            self._launch_groups(kernel, [data, self.state, settings, path_wp], (1,))
        else:
            for stage in structure_explicit.START_STAGES:
                self._stage(kernel, stage, self._count(structure_explicit.KINDS[stage]),
                            settings, path_wp, 0, data=data)
        largest_dt = float(self.group_values("dt").min())
        times = np.append(np.arange(0.0, duration, output_interval), duration)
        first = 0
        if resume_from is None:
            yield self._frame(0.0)
        else:
            first = int(np.argmin(np.abs(times - float(resume_from["time"]))))
            self._restore(resume_from)
        for begin, end in zip(times[first:-1], times[first + 1:]):
            steps = int(np.ceil((end - begin) / largest_dt * (1 - 1e-12)))
            dt = (end - begin) / steps
            for done in range(0, steps, self.chunk):
                run = min(self.chunk, steps - done)
                settings = self._settings(**base, fixed_dt=dt, time=begin + done * dt, chunk=run)
                if grouped:
                    self._launch_groups(kernel, [data, self.state, settings, path_wp], (0,))
                else:
                    for k in range(run):
                        for stage in structure_transient.STEP_STAGES:
                            self._stage(kernel, stage,
                                        self._count(structure_transient.KINDS[stage]),
                                        settings, path_wp, k, data=data)
                codes = self.state.status.numpy()
                if progress is not None:
                    progress(self)
                if (codes != status.RUNNING).any():
                    group = int(np.flatnonzero(codes != status.RUNNING)[0])
                    where = f"group {group}" if name is None else name(group)
                    raise SolverError(f"{where}: the transient stopped at t = "
                                      f"{begin + (done + run) * dt:.6g} s (status "
                                      f"{int(codes[group])}: a non-finite state; dt = {dt:.3g} s "
                                      f"against the predicted stable "
                                      f"{float(self.group_values('stable_dt')[group]):.3g} s)")
            yield self._frame(end)

    def _frame(self, time: float) -> dict:
        read = self.group_values
        return {"time": time, "positions": self.positions(), "velocities": read("velocity"),
                "force": read("force"), "contact_force": read("contact"),
                "friction_force": read("friction"), "anchors": read("anchors"),
                "dissipated": read("dissipated"), "kinetic_energy": read("kinetic_energy")}

    def _restore(self, frame: dict) -> None:
        s = self.state
        for name, field in (("positions", "position"), ("velocities", "velocity"),
                            ("force", "force"), ("anchors", "anchors")):
            getattr(s, field).assign(self._vectors(frame[name]))
        if "dissipated" in frame:
            s.dissipated.assign(self._scalars(frame["dissipated"]))
