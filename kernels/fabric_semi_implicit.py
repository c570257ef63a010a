"""Linearly implicit relaxation of a fabric patch: each time step one conjugate-gradient solve
preconditioned by the yarns' banded solves (docs/model.md sections 5, 10).

The one-yarn semi-implicit step (`kernels/semi_implicit.py`), on the whole patch:

    (M (1 + dt c) + dt^2 K) dv = dt (f - dt K v - c M v),   v += dv,   x += dt v,

with f from `fabric_forces` (F_T at the current R) and K the tangent made positive
semi-definite, F_T frozen:

- each yarn's band (`dynfab.banded` layout in the yarn's own dofs, which are contiguous in
  the flat node order): stretch with a compressed segment's negative geometric part dropped,
  bending k dphi dphi^T with the moment term k (phi - phi0) d2phi dropped (the one-yarn
  solver's `definite`);
- per crossing, the contact's dR/dg >= 0 on (z_wa, z_we) as dR/dg [[1, -1], [-1, 1]];
- per crossing with friction, the exact Huber Hessian on the slip's dofs (x_wa, s_we):
  k_t I while sticking, (F_T / |s|^3) [[s_y^2, -s_x s_y], [-s_x s_y, s_x^2]] while sliding,
  both positive semi-definite (where the planes move, the secant (F_T / |s|) I while sliding:
  the time step rule below);
- where the planes move ("affine", the periodic cell): the rest of J_c^T H_c J_c, J_c carrying
  -w_c on the x dofs of the end nodes moving the crossing's planes (`fabric_forces`); it is
  never stored: the product takes U_f (x summed over family f's end nodes) and
  G_f = sum_c w_c,f (H_c ds_c)_f (`boundary_sums`, one pass) and adds -H_c (w_c o U) on the
  slip dofs and -G_f on the end nodes (`plane_row`);
- the periodic wrap spring at each yarn's node 0 (`add_wrap`): k dphi dphi^T, in the band
  within its pairs (r_{N-1}, r_N) and (r_0, r_1) with the moment term, between the pairs
  in the product (`wrap_row`, from the gradient stored at assembly);
- a tied cell length (periodic force control): one unknown whose n copies sit on the
  family's end nodes. Its row is the sum of theirs (`product_value`), each end node's band
  holding 1/n of the family's mass, and the CG inner products weight each copy 1/n, so CG
  runs on T^T A T, the static solver's unknowns; in P it is its diagonal alone
  (`tie_diagonals`).

The right side dt (f - dt K v - c M v) is dt f + M v - A v, A v by the same product
(`rhs_node`): every coupling of A is in it. Held dofs get identity rows and columns and a
zero right-hand side. With M > 0 the matrix
A = M (1 + dt c) + dt^2 K is symmetric positive definite, but no longer banded: the
crossings couple the yarns. It is solved by conjugate gradients preconditioned by
P = the yarns' own bands of A plus the crossing blocks' diagonal parts (dt^2 dR/dg on each
z, dt^2 h_xx, h_yy on the slip dofs): block-diagonal over yarns and SPD (diagonal blocks of an
SPD matrix, plus nonnegative diagonals), each block factored in O(N BANDWIDTH^2) by banded
LU without pivoting and solved in O(N BANDWIDTH). CG stops when the preconditioned residual
r^T P^-1 r has fallen by CG_TOLERANCE^2 (the P^-1 norm of r by CG_TOLERANCE), or after
as many iterations as dofs. Why 1e-2: the step is accepted or rejected on f^T M^-1 f
anyway, so an inexact step costs at most a rejected step, never a wrong answer; once dt is
large the step is an inexact Newton step on the positive semi-definite tangent, whose
residual falls by about CG_TOLERANCE per step on top of the tangent's own modifications
(the dropped negative parts, F_T frozen). A tighter solve buys few time steps for more CG
iterations, a looser one (1e-1) costs many more time steps on large patches; 1e-2 was
the fastest of 1e-1 to 1e-6 on 16 x 16 and 64 x 64 patches (docs/results.md, "Woven
fabric: semi-implicit against static").

Time step rule: dt starts at 1 s with the Gershgorin masses of
`fabric_arrays.gershgorin_masses` (the explicit solver's). A step that lowers the merit
f^T M^-1 f is accepted and dt doubles (capped at DT_MAX). One that does not is first shortened
along its new velocity, x = x_0 + alpha dt v, alpha = 1/2, 1/4, ... (MAX_BACKTRACKS halvings,
one force evaluation each, the CG solution reused): the first alpha that lowers the merit is
accepted with v scaled by alpha and dt kept; only if none does is the step undone (positions
back, velocities zeroed) and dt halved. Where the planes move ("affine", the periodic cell) a
sliding crossing's friction block is the secant (F_T/|s|) I, a quadratic majorant of the
Huber term (the static solver's after a shortened step), instead of its exact Hessian, which
has no stiffness along s: a step moving the planes shifts every slip of a family at once and
the exact block let it carry slips through the anchors, their friction forces reversing.
A factorisation with a pivot that is not positive (rounding at very large dt) halves dt and
rebuilds. Why (`python benchmarks/fabric_planes.py`, both rules in one run, part
`semi_rules` of benchmarks/fabric_planes.json): the one-yarn rule (undo and halve at once,
`kernels/semi_implicit.py`'s) cycled on the 16 x 16 strip (runs/fabric_strip.toml: affine
planes, friction, weft ends free) between an undone 2 dt and an accepted dt, each accepted
step lowering the merit by a few per cent; the steps that failed reversed the slip of a
sliding crossing or moved a plane's end nodes. The strip's first load step took 779 time
steps (380 undone, 8190 CG iterations), now 167 (65 undone, 2480), 0.26 x the wall time; the
8 x 8 and 16 x 16 patches (fixed, affine, periodic) 0.21 to 0.63 x the time steps, 0.34 to
0.89 x the CG iterations. Measured and dropped: acceptance on the total energy (it stalled
with friction: F_T moving with R is no potential); the secant with fixed planes (16 x 16: 653
CG iterations against 419 with the exact block, the sliding crossings losing Newton's
quadratic convergence); dt held for a step after a shortened one (better with the exact
block on the strip, much worse with the secant); keeping the velocities of an undone step
(stalled). `RULES["halving"]` is the old rule, the exact blocks everywhere (the benchmark's
before).

Two layouts, the same arithmetic in the same order (bit-identical runs; tests check it):

- "persistent" (the CPU's default): one thread running the time loop and every CG
  iteration inside, each stage a loop over the per-unit `wp.func`s, a chunk of time steps
  per launch (`fabric_relaxation.PatchRelaxation.chunks`, the same bits as one launch);
- "per_step" (the GPU's default): the time loop in Python, a launch per stage with a thread
  per crossing (R, friction, the crossing blocks), node (the force gather, the right side,
  the product A p, the move), yarn (the yarn systems and their LU, the preconditioner, the
  per-yarn partial sums) or dof (the CG vector updates), one thread for each total over the
  yarns' partial sums (in yarn order) and for the planes' sums, and the decisions (CG's stop, a step's acceptance, a bad
  pivot) on values read back. No atomics: every thread writes its own slots.

Which pays on the CPU, where a launch runs its threads one after another: the per-step
layout adds 7 launches and a read-back per CG iteration, measured against the work of an
iteration by `python benchmarks/fabric.py --parts newton,semi` (docs/results.md, "Woven
fabric: semi-implicit against static").
"""

import functools
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import warp as wp

from dynfab.banded import BANDWIDTH
from dynfab.kernels import fabric_arrays, fabric_explicit, fabric_forces, status
from dynfab.kernels import bending as bending_module, friction as friction_module
from dynfab.kernels.configuration import MODULE_OPTIONS
from dynfab.kernels.fabric_relaxation import PatchRelaxation, stop_test
from dynfab.kernels.precision import VECTORS

CG_TOLERANCE = 1e-2
"""CG stops at sqrt(r^T P^-1 r / b^T P^-1 b) <= this [-] (see the module docstring)."""
DT_GROWTH = 2.0
"""dt factor after an accepted step [-]."""
DT_SHRINK = 0.5
"""dt factor after a rejected step or a pivot that is not positive [-]."""
DT_MAX = 1e12
"""The largest time step [s]: dt^2 K then outweighs M by ~1e24 (a Newton step); the cap only
keeps dt^2 finite over long runs."""
MAX_BACKTRACKS = 4
"""Halvings of a step's length along its new velocity before the step is undone [-] (the
line search of the module docstring's time step rule)."""
MAX_REFACTORISATIONS = 60
"""dt halvings allowed to obtain positive pivots in one step."""
RULES = {"line_search": MAX_BACKTRACKS, "halving": 0}
"""Time step rules (module docstring): halvings of a step's length before it is undone.
"halving" is the rule before the line search (and the secant friction blocks where the planes
move), kept for the benchmark's before/after."""
STALL_MIN_STEPS = 2_000
"""Time steps after which a relaxation whose residual has not reached a new low during the
last half of its steps stops (status.NO_PROGRESS) instead of running to max_steps."""
WIDTH = 2 * BANDWIDTH + 1
FIRST_CHUNK = 16
"""Time steps of a relaxation's first launch in the persistent layout
(`fabric_relaxation.PatchRelaxation.chunks`; a step is a CG solve)."""


@functools.cache
def work_struct(scalar):
    """The `SemiWork` struct: the solver's arrays (flat dofs 2 i, 2 i + 1 = s, z of node i)."""
    vec = VECTORS[scalar]
    vec4 = wp.types.vector(4, scalar)

    @wp.struct
    class SemiWork:
        yarn_start: wp.array(dtype=wp.int32)  # (Y + 1,) first node of each yarn, then n
        node_yarn: wp.array(dtype=wp.int32)   # (n,) the yarn of each node
        band: wp.array2d(dtype=scalar)        # (2n, WIDTH) A, band[i, j - i + BANDWIDTH] = A_ij
        factor: wp.array2d(dtype=scalar)      # (2n, WIDTH) P's banded LU factors
        coupling: wp.array(dtype=vec4)        # (C,) dR/dg, h_xx, h_xy, h_yy [N/m] of K
        rhs: wp.array(dtype=scalar)           # (2n,) b
        x: wp.array(dtype=scalar)             # (2n,) the CG iterate: dv [m/s]
        r: wp.array(dtype=scalar)             # (2n,) b - A x
        z: wp.array(dtype=scalar)             # (2n,) P^-1 r
        p: wp.array(dtype=scalar)             # (2n,) search direction
        q: wp.array(dtype=scalar)             # (2n,) A p
        partial: wp.array(dtype=scalar)       # (Y,) per-yarn partial dot products
        largest: wp.array(dtype=scalar)       # (Y,) per-yarn largest |f component| [N]
        failed: wp.array(dtype=wp.int32)      # (Y,) per-yarn first bad pivot, or -1
        previous: wp.array(dtype=vec)         # (n,) positions before the step [m]
        wrap_gradient: wp.array(dtype=vec)    # (n,) dphi/dr [1/m] of a wrap spring's 4 nodes
        boundary: wp.array(dtype=scalar)      # (6,) U_x, U_y, G_x, G_y, d_x, d_y (`boundary_sums`)

    return SemiWork


def yarn_starts(arrays: fabric_arrays.PatchArrays) -> np.ndarray:
    """(Y + 1,) the first flat node of each yarn (warps, then wefts), then the node count."""
    return np.concatenate([arrays.warp_nodes[:, 0], arrays.weft_nodes[:, 0],
                           [arrays.nodes]]).astype(np.int32)


def allocate(arrays: fabric_arrays.PatchArrays, scalar, device: str):
    """A zeroed `SemiWork` for the patch `arrays` on `device`."""
    vec, vec4 = VECTORS[scalar], wp.types.vector(4, scalar)
    n, dofs, C = arrays.nodes, 2 * arrays.nodes, arrays.crossings
    start = yarn_starts(arrays)
    work = work_struct(scalar)()
    work.yarn_start = wp.array(start, dtype=wp.int32, device=device)
    work.node_yarn = wp.array(np.repeat(np.arange(start.size - 1), np.diff(start)).astype(np.int32),
                              dtype=wp.int32, device=device)
    work.band = wp.zeros((dofs, WIDTH), dtype=scalar, device=device)
    work.factor = wp.zeros((dofs, WIDTH), dtype=scalar, device=device)
    work.coupling = wp.zeros(C, dtype=vec4, device=device)
    for name in ("rhs", "x", "r", "z", "p", "q"):
        setattr(work, name, wp.zeros(dofs, dtype=scalar, device=device))
    work.partial = wp.zeros(start.size - 1, dtype=scalar, device=device)
    work.largest = wp.zeros(start.size - 1, dtype=scalar, device=device)
    work.failed = wp.zeros(start.size - 1, dtype=wp.int32, device=device)
    work.previous = wp.zeros(n, dtype=vec, device=device)
    work.wrap_gradient = wp.zeros(n, dtype=vec, device=device)
    work.boundary = wp.zeros(6, dtype=scalar, device=device)
    return work


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The per-crossing, per-yarn and per-node `wp.func`s of the semi-implicit step."""
    vec = VECTORS[scalar]
    vec4 = wp.types.vector(4, scalar)
    mat = wp.types.matrix((2, 2), scalar)
    Fabric = fabric_arrays.struct(scalar)
    Work = work_struct(scalar)
    limit = friction_module.functions(scalar).limit
    force_ops = fabric_forces.functions(scalar, True)

    # ---------------------------------------------------------------- band storage

    @wp.func
    def add_block(band: wp.array2d(dtype=scalar), node_p: int, node_q: int, block: mat):
        """A[(p's s, z), (q's s, z)] += block."""
        for c in range(2):
            for d in range(2):
                band[2 * node_p + c, 2 * (node_q - node_p) + d - c + BANDWIDTH] += block[c, d]

    @wp.func
    def constrain(band: wp.array2d(dtype=scalar), lo: int, hi: int, i: int):
        """Row and column i of the band (dofs lo..hi-1 of one yarn) replaced by the identity."""
        for j in range(wp.max(lo, i - BANDWIDTH), wp.min(hi, i + BANDWIDTH + 1)):
            band[i, j - i + BANDWIDTH] = scalar(0.0)
            band[j, i - j + BANDWIDTH] = scalar(0.0)
        band[i, BANDWIDTH] = scalar(1.0)

    @wp.func
    def lu_factor(band: wp.array2d(dtype=scalar), lo: int, hi: int) -> int:
        """Doolittle LU without pivoting of the band's dofs lo..hi-1 in place (`kernels/banded.py`);
        the first pivot that is not positive, or -1."""
        failed = int(-1)
        for k in range(lo, hi):
            pivot = band[k, BANDWIDTH]
            if not pivot > scalar(0.0):
                failed = k
                break
            for i in range(k + 1, wp.min(hi, k + BANDWIDTH + 1)):
                factor = band[i, k - i + BANDWIDTH] / pivot
                band[i, k - i + BANDWIDTH] = factor
                if factor != scalar(0.0):
                    for j in range(k + 1, wp.min(hi, k + BANDWIDTH + 1)):
                        band[i, j - i + BANDWIDTH] = band[i, j - i + BANDWIDTH] \
                            - factor * band[k, j - k + BANDWIDTH]
        return failed

    @wp.func
    def lu_solve(band: wp.array2d(dtype=scalar), lo: int, hi: int, rhs: wp.array(dtype=scalar)):
        """rhs[lo:hi] = A^-1 rhs[lo:hi] with the factors of `lu_factor`."""
        for i in range(lo, hi):
            total = rhs[i]
            for j in range(wp.max(lo, i - BANDWIDTH), i):
                total -= band[i, j - i + BANDWIDTH] * rhs[j]
            rhs[i] = total
        for step in range(hi - lo):
            i = hi - 1 - step
            total = rhs[i]
            for j in range(i + 1, wp.min(hi, i + BANDWIDTH + 1)):
                total -= band[i, j - i + BANDWIDTH] * rhs[j]
            rhs[i] = total / band[i, BANDWIDTH]

    # ---------------------------------------------------------------- the tangent K

    theta_hessian = bending_module.functions(scalar).theta_hessian  # d2theta/dv2 [1/m^2]

    @wp.func
    def add_stretch(band: wp.array2d(dtype=scalar), pos: wp.array(dtype=vec), fabric: Fabric,
                    i: int, definite: int):
        """Segment (i, i+1): k [e e^T / l^2 + (1 - l0/l)(I - e e^T / l^2)], the geometric part
        dropped where negative with `definite`."""
        e = pos[i + 1] - pos[i]
        l2 = wp.dot(e, e)
        geometric = scalar(1.0) - fabric.rest_length[i] / wp.sqrt(l2)
        if definite != 0:
            geometric = wp.max(geometric, scalar(0.0))
        axial = wp.outer(e, e) / l2
        block = fabric.stretch_stiffness[i] * (axial + geometric * (wp.identity(2, scalar) - axial))
        add_block(band, i, i, block)
        add_block(band, i + 1, i + 1, block)
        add_block(band, i, i + 1, -block)
        add_block(band, i + 1, i, -block)

    @wp.func
    def add_bending(band: wp.array2d(dtype=scalar), pos: wp.array(dtype=vec), fabric: Fabric,
                    i: int, definite: int):
        """Spring at node i: k dphi dphi^T + k (phi - phi0) d2phi over nodes (i-1, i, i+1), the
        moment term dropped with `definite` (`kernels/bending.py`)."""
        a = pos[i] - pos[i - 1]
        b = pos[i + 1] - pos[i]
        k = fabric.bend_stiffness[i]
        moment = k * (wp.atan2(a[0] * b[1] - a[1] * b[0], wp.dot(a, b)) - fabric.rest_angle[i])
        if definite != 0:
            moment = scalar(0.0)
        ga = vec(a[1], -a[0]) / wp.dot(a, a)
        gb = vec(-b[1], b[0]) / wp.dot(b, b)
        ha = -moment * theta_hessian(a)
        hb = moment * theta_hessian(b)
        # dphi/dr = (-g_a, g_a - g_b, g_b); d2phi = -S_a^T H(a) S_a + S_b^T H(b) S_b
        g0 = -ga
        g1 = ga - gb
        g2 = gb
        add_block(band, i - 1, i - 1, k * wp.outer(g0, g0) + ha)
        add_block(band, i - 1, i, k * wp.outer(g0, g1) - ha)
        add_block(band, i - 1, i + 1, k * wp.outer(g0, g2))
        add_block(band, i, i - 1, k * wp.outer(g1, g0) - ha)
        add_block(band, i, i, k * wp.outer(g1, g1) + ha + hb)
        add_block(band, i, i + 1, k * wp.outer(g1, g2) - hb)
        add_block(band, i + 1, i - 1, k * wp.outer(g2, g0))
        add_block(band, i + 1, i, k * wp.outer(g2, g1) - hb)
        add_block(band, i + 1, i + 1, k * wp.outer(g2, g2) + hb)

    @wp.func
    def add_pair(band: wp.array2d(dtype=scalar), start: int, end: int, block: mat):
        """block on (start, start) and (end, end), -block on (start, end) and (end, start)."""
        add_block(band, start, start, block)
        add_block(band, end, end, block)
        add_block(band, start, end, -block)
        add_block(band, end, start, -block)

    @wp.func
    def add_wrap(band: wp.array2d(dtype=scalar), pos: wp.array(dtype=vec), fabric: Fabric,
                 work: Work, first: int, definite: int):
        """The periodic wrap spring at node `first` (docs/model.md section 10) between
        a = r_N - r_{N-1} and b = r_1 - r_0: its gradient dphi/dr = (-g_a, g_a, -g_b, g_b) on
        (r_{N-1}, r_N, r_0, r_1) into work.wrap_gradient; into the band, k dphi dphi^T within
        each segment's pair of nodes and the moment term k (phi - phi0) d2phi (dropped with
        `definite`), which lies within the pairs. The blocks between the pairs, far apart along
        the yarn and outside the band, are `wrap_row`'s."""
        last = fabric.yarn_last[first]
        a = pos[last] - pos[last - 1]
        b = pos[first + 1] - pos[first]
        k = fabric.wrap_stiffness[first]
        moment = k * (force_ops.turning_angle(a, b) - fabric.wrap_rest_angle[first])
        if definite != 0:
            moment = scalar(0.0)
        ga = vec(a[1], -a[0]) / wp.dot(a, a)
        gb = vec(-b[1], b[0]) / wp.dot(b, b)
        work.wrap_gradient[last - 1] = -ga
        work.wrap_gradient[last] = ga
        work.wrap_gradient[first] = -gb
        work.wrap_gradient[first + 1] = gb
        add_pair(band, last - 1, last, k * wp.outer(ga, ga) - moment * theta_hessian(a))
        add_pair(band, first, first + 1, k * wp.outer(gb, gb) + moment * theta_hessian(b))

    @wp.func
    def crossing_blocks(c: int, pos: wp.array(dtype=vec), fabric: Fabric,
                        anchors: wp.array(dtype=vec), contact: wp.array(dtype=scalar), work: Work,
                        shift: vec, secant: int):
        """coupling[c] = (dR/dg, h_xx, h_xy, h_yy) [N/m] at R = contact[c] (this position's),
        F_T frozen at F_T(R): dR/dg of the series law where closed (0 open); the Huber Hessian
        at the slip s (the planes moved by `shift`, `fabric_forces.plane_shift`), 0 where
        F_T = 0, with `secant` the secant (F_T/|s|) I where sliding."""
        law = fabric.contact_law
        R = contact[c]
        g = fabric.crossing_offset[c] - fabric.crossing_side[c] * (
            pos[fabric.crossing_warp[c]][1] - pos[fabric.crossing_weft[c]][1])
        tangent = scalar(0.0)
        if g > scalar(0.0):
            tangent = scalar(1.0) / (scalar(1.0) / law[0] + law[1] * law[2] * wp.exp(-law[2] * R)
                                     + law[3] * law[4] * wp.exp(-law[4] * R))
        h = vec(scalar(0.0), scalar(0.0))
        cross = scalar(0.0)
        friction = fabric.friction_law
        stick = friction[3]
        bound = limit(R, friction[0], friction[1], friction[2])
        if stick > scalar(0.0) and bound > scalar(0.0):
            s = force_ops.slip(pos, fabric, anchors, c, shift)
            size = wp.length(s)
            if stick * size <= bound:
                h = vec(stick, stick)
            elif secant != 0:
                h = vec(bound / size, bound / size)
            else:
                scale = bound / (size * size * size)
                h = vec(scale * s[1] * s[1], scale * s[0] * s[0])
                cross = -scale * s[0] * s[1]
        work.coupling[c] = vec4(tangent, h[0], cross, h[1])

    @wp.func
    def crossing_term(blk: vec4, comp: int, on_warp: bool, own: scalar, partner: scalar) -> scalar:
        """One row of a crossing's block of K times a vector [N]: `own` is the vector at the
        row's dof, `partner` at the crossing's other node, same component (z: the contact's
        dR/dg (own - partner); in-plane: the Huber block, h_xx/h_xy on the warp's x row,
        h_xy/h_yy on the weft's y row)."""
        value = blk[0] * (own - partner)
        if comp == 0:
            if on_warp:
                value = blk[1] * own + blk[2] * partner
            else:
                value = blk[2] * partner + blk[3] * own
        return value

    @wp.func
    def crossing_partner(i: int, c: int, fabric: Fabric) -> int:
        """The node that crossing c joins to node i."""
        partner = fabric.crossing_warp[c]
        if partner == i:
            partner = fabric.crossing_weft[c]
        return partner

    @wp.func
    def coupling_row(i: int, comp: int, x: wp.array(dtype=scalar), fabric: Fabric,
                     work: Work) -> scalar:
        """(K_crossings x) at dof (node i, component comp) [N], x flat."""
        c = fabric.node_crossing[i]
        total = scalar(0.0)
        if c >= 0:
            partner = crossing_partner(i, c, fabric)
            total = crossing_term(work.coupling[c], comp, fabric.crossing_warp[c] == i,
                                  x[2 * i + comp], x[2 * partner + comp])
        return total

    @wp.func
    def coupling_diagonal(i: int, comp: int, fabric: Fabric, work: Work) -> scalar:
        """K_crossings' diagonal entry at dof (node i, comp) [N/m]."""
        c = fabric.node_crossing[i]
        value = scalar(0.0)
        if c >= 0:
            blk = work.coupling[c]
            if comp == 1:
                value = blk[0]
            elif fabric.crossing_warp[c] == i:
                value = blk[1]
            else:
                value = blk[3]
        return value

    @wp.func
    def members(fabric: Fabric, i: int) -> int:
        """n for an end node of a tied family of n (one dof, its copies on n nodes), else 1."""
        family = fabric.node_tie[i]
        count = int(1)
        if family >= 0:
            count = fabric.plane_offsets[family + 1] - fabric.plane_offsets[family]
        return count

    @wp.func
    def wrap_row(i: int, comp: int, x: wp.array(dtype=scalar), fabric: Fabric,
                 work: Work) -> scalar:
        """The wrap spring's k dphi dphi^T between its two pairs of nodes times x, at dof
        (node i, comp) [N]: k g_i (g_other . x_other) over the other pair (`add_wrap`)."""
        first = fabric.node_wrap[i]
        value = scalar(0.0)
        if first >= 0:
            other = first
            if i < fabric.yarn_last[first] - 1:  # i in (r_0, r_1): the other pair ends the yarn
                other = fabric.yarn_last[first] - 1
            g = work.wrap_gradient
            along = (wp.dot(g[other], vec(x[2 * other], x[2 * other + 1]))
                     + wp.dot(g[other + 1], vec(x[2 * other + 2], x[2 * other + 3])))
            value = fabric.wrap_stiffness[first] * g[i][comp] * along
        return value

    @wp.func
    def plane_row(i: int, comp: int, fabric: Fabric, work: Work) -> scalar:
        """The moving planes' part of the friction block J^T H J times x at dof (node i,
        comp) [N], from `boundary_sums` of x: -H (w_c o U) on a crossing's slip dofs, -G_f on
        an end node moving family f's planes (0 with fixed planes)."""
        value = scalar(0.0)
        if comp == 0:
            c = fabric.node_crossing[i]
            if c >= 0:
                moved = wp.cw_mul(fabric.crossing_plane_weight[c],
                                  vec(work.boundary[0], work.boundary[1]))
                blk = work.coupling[c]
                if fabric.crossing_warp[c] == i:
                    value = -(blk[1] * moved[0] + blk[2] * moved[1])
                else:
                    value = -(blk[2] * moved[0] + blk[3] * moved[1])
            family = fabric.node_plane[i]
            if family >= 0:
                value = value - work.boundary[2 + family]
        return value

    @wp.func
    def boundary_sums(x: wp.array(dtype=scalar), fabric: Fabric, work: Work):
        """boundary[0:4] = (U_x, U_y, G_x, G_y) of x (flat) where the planes move: U_f the sum
        of x over family f's plane nodes, G_f = sum_c w_c,f (H_c ds_c)_f with ds_c = (x_wa,
        x_we) - w_c o U the slip's change (crossing order). Nothing with fixed planes."""
        if fabric.plane_offsets[2] > 0:
            U = vec(scalar(0.0), scalar(0.0))
            for family in range(2):
                total = scalar(0.0)
                for m in range(fabric.plane_offsets[family], fabric.plane_offsets[family + 1]):
                    total += x[2 * fabric.plane_nodes[m]]
                U[family] = total
            G = vec(scalar(0.0), scalar(0.0))
            for c in range(fabric.crossing_warp.shape[0]):
                w = fabric.crossing_plane_weight[c]
                blk = work.coupling[c]
                ds = vec(x[2 * fabric.crossing_warp[c]], x[2 * fabric.crossing_weft[c]]) \
                    - wp.cw_mul(w, U)
                G = G + wp.cw_mul(w, vec(blk[1] * ds[0] + blk[2] * ds[1],
                                         blk[2] * ds[0] + blk[3] * ds[1]))
            work.boundary[0] = U[0]
            work.boundary[1] = U[1]
            work.boundary[2] = G[0]
            work.boundary[3] = G[1]

    @wp.func
    def tie_diagonals(fabric: Fabric, work: Work, dt2: scalar):
        """boundary[4 + f] = the preconditioner's entry for tied family f's one dof: its
        nodes' band diagonals plus dt^2 sum_c (n w_c,f)^2 h_c,ff (the planes' part)."""
        for family in range(2):
            begin = fabric.plane_offsets[family]
            end = fabric.plane_offsets[family + 1]
            if end > begin:
                if fabric.node_tie[fabric.plane_nodes[begin]] >= 0:
                    total = scalar(0.0)
                    for m in range(begin, end):
                        total += work.band[2 * fabric.plane_nodes[m], BANDWIDTH]
                    planes = scalar(0.0)
                    for c in range(fabric.crossing_warp.shape[0]):
                        w = scalar(end - begin) * fabric.crossing_plane_weight[c][family]
                        planes += w * w * work.coupling[c][1 + 2 * family]
                    work.boundary[4 + family] = total + dt2 * planes

    @wp.func
    def band_row(row: int, x: wp.array(dtype=scalar), band: wp.array2d(dtype=scalar)) -> scalar:
        """sum_j band[row, j] x_j over the band (entries of other yarns are zero)."""
        total = scalar(0.0)
        for j in range(wp.max(0, row - BANDWIDTH), wp.min(x.shape[0], row + BANDWIDTH + 1)):
            total += band[row, j - row + BANDWIDTH] * x[j]
        return total

    @wp.func
    def free_dof(fabric: Fabric, row: int) -> scalar:
        """1 for a free dof, 0 for a held one."""
        return fabric.free[row / 2][row % 2]

    @wp.func
    def build_yarn(y: int, pos: wp.array(dtype=vec), mass: wp.array(dtype=scalar), fabric: Fabric,
                   work: Work, dt: scalar, damping: scalar, definite: int) -> int:
        """Yarn y's rows of A = M (1 + dt c) + dt^2 K_yarn in the band (held dofs: identity; a
        tied node's mass its share, the n copies of its dof summing to the family's mass), and
        factor = the LU of that plus dt^2 the crossing diagonals, a tied dof's row and column
        the identity (its preconditioner is `tie_diagonals`'). Needs coupling
        (`crossing_blocks`) of every crossing. Returns the first pivot that is not positive,
        or -1."""
        a = work.yarn_start[y]
        b = work.yarn_start[y + 1]
        lo = 2 * a
        hi = 2 * b
        band = work.band
        for row in range(lo, hi):
            for k in range(WIDTH):
                band[row, k] = scalar(0.0)
        for i in range(a, b - 1):
            add_stretch(band, pos, fabric, i, definite)
        for i in range(a + 1, b - 1):
            add_bending(band, pos, fabric, i, definite)
        if fabric.wrap_stiffness[a] > scalar(0.0):
            add_wrap(band, pos, fabric, work, a, definite)
        dt2 = dt * dt
        for row in range(lo, hi):
            for k in range(WIDTH):
                band[row, k] = dt2 * band[row, k]
            band[row, BANDWIDTH] += (scalar(1.0) + dt * damping) * mass[row / 2] / scalar(
                members(fabric, row / 2))
        for row in range(lo, hi):
            if free_dof(fabric, row) == scalar(0.0):
                constrain(band, lo, hi, row)
        for row in range(lo, hi):
            for k in range(WIDTH):
                work.factor[row, k] = band[row, k]
            work.factor[row, BANDWIDTH] += dt2 * free_dof(fabric, row) * coupling_diagonal(
                row / 2, row % 2, fabric, work)
        for i in range(a, b):
            if fabric.node_tie[i] >= 0:
                constrain(work.factor, lo, hi, 2 * i)
        return lu_factor(work.factor, lo, hi)

    # ---------------------------------------------------------------- PCG pieces

    @wp.func
    def own_row(i: int, comp: int, x: wp.array(dtype=scalar), fabric: Fabric, work: Work,
                dt2: scalar) -> scalar:
        """(A x) at dof (node i, comp) from node i's own row (x zero on held dofs): the band,
        dt^2 the crossing, planes and wrap spring (`boundary_sums` of x done)."""
        row = 2 * i + comp
        return band_row(row, x, work.band) + dt2 * free_dof(fabric, row) * (
            coupling_row(i, comp, x, fabric, work) + plane_row(i, comp, fabric, work)
            + wrap_row(i, comp, x, fabric, work))

    @wp.func
    def product_value(i: int, comp: int, x: wp.array(dtype=scalar), fabric: Fabric, work: Work,
                      dt2: scalar) -> scalar:
        """(A x) at dof (node i, comp); on a tied node's x, the family's rows summed in
        plane-node order (T^T A T x, the same value on every copy)."""
        family = fabric.node_tie[i]
        value = scalar(0.0)
        if comp == 0 and family >= 0:
            for m in range(fabric.plane_offsets[family], fabric.plane_offsets[family + 1]):
                value += own_row(fabric.plane_nodes[m], 0, x, fabric, work, dt2)
        else:
            value = own_row(i, comp, x, fabric, work, dt2)
        return value

    @wp.func
    def product_node(i: int, x: wp.array(dtype=scalar), y_out: wp.array(dtype=scalar),
                     fabric: Fabric, work: Work, dt2: scalar):
        """y_out = A x at node i's two dofs (x zero on held dofs, `boundary_sums` of x done)."""
        for comp in range(2):
            y_out[2 * i + comp] = product_value(i, comp, x, fabric, work, dt2)

    @wp.func
    def velocity_dofs(d: int, vel: wp.array(dtype=vec), work: Work):
        """x[d] = v at flat dof d (the right side's product reads it)."""
        work.x[d] = vel[d / 2][d % 2]

    @wp.func
    def rhs_node(i: int, vel: wp.array(dtype=vec), force: wp.array(dtype=vec),
                 mass: wp.array(dtype=scalar), fabric: Fabric, work: Work, dt: scalar):
        """rhs = dt (f - dt K v - c M v) = dt f + M v - A v at node i's dofs (0 on held ones),
        A v from x = v (`velocity_dofs`, `boundary_sums` of it): the product CG uses, so K v has
        every coupling A has. A tied node's f and m are its family's (`fabric_forces`,
        `fabric_arrays.gershgorin_masses`)."""
        for comp in range(2):
            row = 2 * i + comp
            work.rhs[row] = free_dof(fabric, row) * (
                dt * force[i][comp] + mass[i] * vel[i][comp]
                - product_value(i, comp, work.x, fabric, work, dt * dt))

    @wp.func
    def precondition_yarn(y: int, fabric: Fabric, work: Work):
        """z = P^-1 r on yarn y's dofs; a tied dof's z = r / its `tie_diagonals` entry."""
        a = work.yarn_start[y]
        b = work.yarn_start[y + 1]
        for row in range(2 * a, 2 * b):
            work.z[row] = work.r[row]
        lu_solve(work.factor, 2 * a, 2 * b, work.z)
        for i in range(a, b):
            family = fabric.node_tie[i]
            if family >= 0:
                work.z[2 * i] = work.r[2 * i] / work.boundary[4 + family]

    @wp.func
    def yarn_dot(y: int, u: wp.array(dtype=scalar), w: wp.array(dtype=scalar), fabric: Fabric,
                 work: Work) -> scalar:
        """sum of u w over yarn y's dofs, in order, a tied dof's n copies each weighted 1/n
        (the reduced system's inner product)."""
        total = scalar(0.0)
        for i in range(work.yarn_start[y], work.yarn_start[y + 1]):
            total += u[2 * i] * w[2 * i] / scalar(members(fabric, i))
            total += u[2 * i + 1] * w[2 * i + 1]
        return total

    @wp.func
    def dot(u: wp.array(dtype=scalar), w: wp.array(dtype=scalar), fabric: Fabric,
            work: Work) -> scalar:
        """u . w: per-yarn sums added in yarn order (the GPU layout's order)."""
        total = scalar(0.0)
        for y in range(work.partial.shape[0]):
            total += yarn_dot(y, u, w, fabric, work)
        return total

    @wp.func
    def pcg(fabric: Fabric, work: Work, dt2: scalar, tolerance: scalar, max_iterations: int) -> int:
        """x = A^-1 rhs by preconditioned CG from x = 0; returns the iterations taken."""
        dofs = work.x.shape[0]
        yarns = work.partial.shape[0]
        nodes = dofs / 2
        for d in range(dofs):
            work.x[d] = scalar(0.0)
            work.r[d] = work.rhs[d]
        for y in range(yarns):
            precondition_yarn(y, fabric, work)
        rz = dot(work.r, work.z, fabric, work)
        stop = tolerance * tolerance * rz
        for d in range(dofs):
            work.p[d] = work.z[d]
        iterations = int(0)
        while iterations < max_iterations and rz > stop:
            boundary_sums(work.p, fabric, work)
            for i in range(nodes):
                product_node(i, work.p, work.q, fabric, work, dt2)
            pq = dot(work.p, work.q, fabric, work)
            if not pq > scalar(0.0):
                break
            alpha = rz / pq
            for d in range(dofs):
                work.x[d] = work.x[d] + alpha * work.p[d]
                work.r[d] = work.r[d] - alpha * work.q[d]
            for y in range(yarns):
                precondition_yarn(y, fabric, work)
            rz_new = dot(work.r, work.z, fabric, work)
            beta = rz_new / rz
            rz = rz_new
            for d in range(dofs):
                work.p[d] = work.z[d] + beta * work.p[d]
            iterations += 1
        return iterations

    @wp.func
    def build_system(pos: wp.array(dtype=vec), vel: wp.array(dtype=vec), force: wp.array(dtype=vec),
                     mass: wp.array(dtype=scalar), fabric: Fabric, anchors: wp.array(dtype=vec),
                     contact: wp.array(dtype=scalar), work: Work, dt: scalar, damping: scalar,
                     definite: int, secant: int) -> int:
        """Every crossing's blocks (`secant`: see `crossing_blocks`), every yarn's system, then
        the right side; -1, or a yarn's bad pivot."""
        shift = force_ops.plane_shift(pos, fabric)
        for c in range(contact.shape[0]):
            crossing_blocks(c, pos, fabric, anchors, contact, work, shift, secant)
        failed = int(-1)
        for y in range(work.partial.shape[0]):
            bad = build_yarn(y, pos, mass, fabric, work, dt, damping, definite)
            if bad >= 0 and failed < 0:
                failed = bad
        for d in range(work.x.shape[0]):
            velocity_dofs(d, vel, work)
        boundary_sums(work.x, fabric, work)
        tie_diagonals(fabric, work, dt * dt)
        for i in range(pos.shape[0]):
            rhs_node(i, vel, force, mass, fabric, work, dt)
        return failed

    @wp.func
    def larger(worst: scalar, value: scalar) -> scalar:
        """max(worst, |value|), a NaN kept once met."""
        result = worst
        if worst == worst and not wp.abs(value) <= worst:
            result = wp.abs(value)
        return result

    @wp.func
    def yarn_merit(y: int, force: wp.array(dtype=vec), mass: wp.array(dtype=scalar),
                   fabric: Fabric, work: Work) -> vec:
        """(largest |f component| [N], sum f^T f / m [N^2/kg]) over yarn y's nodes, in order, a
        tied family's n copies of its dof each counted 1/n."""
        worst = scalar(0.0)
        total = scalar(0.0)
        for i in range(work.yarn_start[y], work.yarn_start[y + 1]):
            f = force[i]
            total += wp.dot(f, f) / mass[i] / scalar(members(fabric, i))
            worst = larger(larger(worst, f[0]), f[1])
        return vec(worst, total)

    @wp.func
    def merit_total(work: Work) -> vec:
        """(residual, f^T M^-1 f) from the per-yarn values, in yarn order."""
        worst = scalar(0.0)
        total = scalar(0.0)
        for y in range(work.partial.shape[0]):
            worst = larger(worst, work.largest[y])
            total += work.partial[y]
        return vec(worst, total)

    @wp.func
    def move_node(i: int, pos: wp.array(dtype=vec), vel: wp.array(dtype=vec), work: Work,
                  dt: scalar):
        """previous = x, v += dv, x += dt v at node i."""
        work.previous[i] = pos[i]
        v = vel[i] + vec(work.x[2 * i], work.x[2 * i + 1])
        vel[i] = v
        pos[i] = pos[i] + dt * v

    @wp.func
    def undo_node(i: int, pos: wp.array(dtype=vec), vel: wp.array(dtype=vec), work: Work):
        """Back to the step's start, at rest."""
        pos[i] = work.previous[i]
        vel[i] = vec(scalar(0.0), scalar(0.0))

    @wp.func
    def trial_node(i: int, pos: wp.array(dtype=vec), vel: wp.array(dtype=vec), work: Work,
                   length: scalar):
        """x = previous + length v at node i: the step shortened to length = alpha dt [s]."""
        pos[i] = work.previous[i] + length * vel[i]

    @wp.func
    def scale_node(i: int, vel: wp.array(dtype=vec), alpha: scalar):
        """v *= alpha at node i (a shortened step keeps the velocity of its length)."""
        vel[i] = alpha * vel[i]

    return SimpleNamespace(crossing_blocks=crossing_blocks, build_yarn=build_yarn,
                           product_node=product_node, precondition_yarn=precondition_yarn,
                           velocity_dofs=velocity_dofs, boundary_sums=boundary_sums,
                           tie_diagonals=tie_diagonals, rhs_node=rhs_node,
                           yarn_dot=yarn_dot, dot=dot, pcg=pcg, build_system=build_system,
                           yarn_merit=yarn_merit, merit_total=merit_total, move_node=move_node,
                           undo_node=undo_node, trial_node=trial_node, scale_node=scale_node)


@functools.cache
def system_kernel(scalar):
    """One thread: with `assemble`, forces at pos, then A, rhs and P; with `solve`,
    x = A^-1 rhs by PCG (the persistent layout's solve); with `apply`, q = A p (p as given);
    outcome[0] = the first bad pivot (-1), outcome[1] = CG iterations. For tests and the
    benchmark's layout comparison."""
    vec = VECTORS[scalar]
    Fabric, Work = fabric_arrays.struct(scalar), work_struct(scalar)
    ops, force_ops = functions(scalar), fabric_forces.functions(scalar, True)

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def system(fabric: Fabric, work: Work, mass: wp.array(dtype=scalar),
               external: wp.array(dtype=vec),
               anchors: wp.array(dtype=vec), pos: wp.array(dtype=vec), vel: wp.array(dtype=vec),
               force: wp.array(dtype=vec), contact: wp.array(dtype=scalar),
               friction: wp.array(dtype=vec), dt: scalar, damping: scalar, definite: int,
               secant: int, assemble: int, solve: int, apply: int, tolerance: scalar,
               max_iterations: int, outcome: wp.array(dtype=wp.int32)):
        if assemble != 0:
            force_ops.scatter_forces(pos, fabric, anchors, contact, friction, external, force)
            outcome[0] = ops.build_system(pos, vel, force, mass, fabric, anchors, contact, work,
                                          dt, damping, definite, secant)
        outcome[1] = 0
        if solve != 0:
            outcome[1] = ops.pcg(fabric, work, dt * dt, tolerance, max_iterations)
        if apply != 0:
            ops.boundary_sums(work.p, fabric, work)
            for i in range(pos.shape[0]):
                ops.product_node(i, work.p, work.q, fabric, work, dt * dt)

    return system


@functools.cache
def relaxation_kernel(scalar):
    """One thread relaxes the patch: the time loop, the systems and CG inside (layout
    "persistent"); friction always compiled in (F_T = k_t = 0 without it)."""
    vec = VECTORS[scalar]
    Fabric, Work = fabric_arrays.struct(scalar), work_struct(scalar)
    ops, force_ops = functions(scalar), fabric_forces.functions(scalar, True)
    stop = stop_test(scalar)

    @wp.func
    def evaluate(fabric: Fabric, work: Work, mass: wp.array(dtype=scalar),
                 external: wp.array(dtype=vec), anchors: wp.array(dtype=vec),
                 pos: wp.array(dtype=vec),
                 force: wp.array(dtype=vec), contact: wp.array(dtype=scalar),
                 friction: wp.array(dtype=vec)) -> vec:
        """Forces at pos; returns (max |f component| [N], f^T M^-1 f [N^2/kg]). The per-step
        layout's order: the crossing pass, the per-node gather, per-yarn sums added in yarn
        order (bit-identical layouts; the forces are a small part of a step's cost)."""
        for c in range(contact.shape[0]):
            force_ops.crossing_pass(pos, fabric, anchors, contact, friction, c)
        for i in range(pos.shape[0]):
            force[i] = force_ops.node_force(i, pos, fabric, contact, friction, external)
        for y in range(work.partial.shape[0]):
            value = ops.yarn_merit(y, force, mass, fabric, work)
            work.largest[y] = value[0]
            work.partial[y] = value[1]
        return ops.merit_total(work)

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def relax(fabric: Fabric, work: Work, mass: wp.array(dtype=scalar),
              external: wp.array(dtype=vec), anchors: wp.array(dtype=vec), dt_start: scalar,
              damping: scalar, tolerance: scalar, cg_tolerance: scalar, max_steps: int,
              first: int, stop_at: int, carry: wp.array(dtype=scalar),
              counters: wp.array(dtype=wp.int32),
              backtracks: int, secant: int, pos: wp.array(dtype=vec), vel: wp.array(dtype=vec),
              force: wp.array(dtype=vec), contact: wp.array(dtype=scalar),
              friction: wp.array(dtype=vec), outcome: wp.array(dtype=wp.int32),
              residual_out: wp.array(dtype=scalar)):
        """Steps `first`, first + 1, ... until residual <= tolerance or max_steps; outcome =
        (status, steps, CG iterations, rejected steps, shortened steps, evaluations at
        shortened lengths); or until step `stop_at` (status RUNNING: a later launch from
        first = stop_at continues with the same bits, from what the loop carries between
        steps: `carry` (dt, residual, merit, best residual) and `counters` (steps since the
        best, CG iterations, rejected, shortened, trials), the forces and the work arrays as
        the last evaluation left them)."""
        nodes = pos.shape[0]
        dofs = 2 * nodes
        dt = dt_start
        residual = scalar(0.0)
        merit = scalar(0.0)
        best = scalar(0.0)
        since_best = int(0)
        code = int(status.MAX_STEPS)
        steps = int(first)
        iterations = int(0)
        rejected = int(0)
        shortened = int(0)
        trials = int(0)
        state = vec(scalar(0.0), scalar(0.0))
        if first == 0:
            state = evaluate(fabric, work, mass, external, anchors, pos, force, contact, friction)
            residual = state[0]
            merit = state[1]
            best = residual
        else:  # a continued relaxation
            dt = carry[0]
            residual = carry[1]
            merit = carry[2]
            best = carry[3]
            since_best = int(counters[0])
            iterations = int(counters[1])
            rejected = int(counters[2])
            shortened = int(counters[3])
            trials = int(counters[4])
        for step in range(first, max_steps + 1):
            if step == stop_at:
                code = int(status.RUNNING)
                break
            code = stop(wp.isfinite(residual) and wp.isfinite(merit), residual, tolerance, step,
                        max_steps)
            if code != int(status.RUNNING):
                break
            if step >= STALL_MIN_STEPS and 2 * since_best > step:
                code = int(status.NO_PROGRESS)
                break
            factored = bool(False)
            for _ in range(MAX_REFACTORISATIONS):
                if ops.build_system(pos, vel, force, mass, fabric, anchors, contact, work, dt,
                                    damping, 1, secant) < 0:
                    factored = True
                    break
                dt = dt * scalar(DT_SHRINK)
            if not factored:
                code = int(status.NOT_POSITIVE_DEFINITE)
                break
            iterations += ops.pcg(fabric, work, dt * dt, cg_tolerance, dofs)
            for i in range(nodes):
                ops.move_node(i, pos, vel, work, dt)
            state = evaluate(fabric, work, mass, external, anchors, pos, force, contact, friction)
            alpha = scalar(1.0)
            for _ in range(backtracks):  # the step halved along its velocity
                if state[1] < merit:
                    break
                alpha = alpha * scalar(0.5)
                trials += 1
                for i in range(nodes):
                    ops.trial_node(i, pos, vel, work, alpha * dt)
                state = evaluate(fabric, work, mass, external, anchors, pos, force, contact,
                                 friction)
            if state[1] < merit:
                merit = state[1]
                if alpha < scalar(1.0):  # v of the length taken; dt kept
                    shortened += 1
                    for i in range(nodes):
                        ops.scale_node(i, vel, alpha)
                else:
                    dt = wp.min(dt * scalar(DT_GROWTH), scalar(DT_MAX))
            else:  # undo: back to the step's start at rest, dt halved
                rejected += 1
                dt = dt * scalar(DT_SHRINK)
                for i in range(nodes):
                    ops.undo_node(i, pos, vel, work)
                state = evaluate(fabric, work, mass, external, anchors, pos, force, contact,
                                 friction)
            residual = state[0]
            if residual < best:
                best = residual
                since_best = 0
            else:
                since_best += 1
            steps = step + 1
        outcome[0] = code
        outcome[1] = steps
        outcome[2] = iterations
        outcome[3] = rejected
        outcome[4] = shortened
        outcome[5] = trials
        residual_out[0] = residual
        carry[0] = dt
        carry[1] = residual
        carry[2] = merit
        carry[3] = best
        counters[0] = wp.int32(since_best)
        counters[1] = wp.int32(iterations)
        counters[2] = wp.int32(rejected)
        counters[3] = wp.int32(shortened)
        counters[4] = wp.int32(trials)

    return relax


START, PRECONDITION, FIRST_SUM, COPY_DIRECTION, BOUNDARY, PRODUCT, CURVATURE, STEP_LENGTH, \
    UPDATE, NEXT_SUM, DIRECTION = range(11)
"""The stages of `stage_kernel`."""


@functools.cache
def stage_kernel(scalar):
    """The launch-per-stage layout of one PCG solve: one kernel, its stage chosen per launch
    (one module to compile), a thread per dof, node or yarn, or one thread for each reduction
    over the yarns' partial sums, in yarn order: the GPU's layout, the same arithmetic in the
    same order as `functions.pcg` (bit-identical x). `scalars` = (r^T z, stop, alpha, beta,
    done, iterations)."""
    Fabric, Work = fabric_arrays.struct(scalar), work_struct(scalar)
    ops = functions(scalar)

    @wp.func
    def partial_sum(work: Work) -> scalar:
        total = scalar(0.0)
        for y in range(work.partial.shape[0]):
            total += work.partial[y]
        return total

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def stage_pass(fabric: Fabric, work: Work, dt2: scalar, tolerance: scalar,
                   scalars: wp.array(dtype=scalar), stage: int):
        t = wp.tid()
        done = scalars[4] != scalar(0.0)
        if stage == START:  # x = 0, r = b (per dof)
            work.x[t] = scalar(0.0)
            work.r[t] = work.rhs[t]
        elif stage == PRECONDITION:  # z = P^-1 r, partial = r . z (per yarn)
            ops.precondition_yarn(t, fabric, work)
            work.partial[t] = ops.yarn_dot(t, work.r, work.z, fabric, work)
        elif stage == FIRST_SUM:  # r^T z and the stopping value (one thread)
            total = partial_sum(work)
            scalars[0] = total
            scalars[1] = tolerance * tolerance * total
            scalars[4] = scalar(0.0)
            if not total > scalars[1]:
                scalars[4] = scalar(1.0)
        elif stage == COPY_DIRECTION:  # p = z (per dof)
            work.p[t] = work.z[t]
        elif stage == BOUNDARY:  # the planes' sums of p (one thread; moving planes only)
            ops.boundary_sums(work.p, fabric, work)
        elif stage == PRODUCT:  # q = A p (per node)
            ops.product_node(t, work.p, work.q, fabric, work, dt2)
        elif stage == CURVATURE:  # partial = p . q (per yarn)
            work.partial[t] = ops.yarn_dot(t, work.p, work.q, fabric, work)
        elif stage == STEP_LENGTH:  # alpha, or done where p^T A p is not positive (one thread)
            total = partial_sum(work)
            if not done:
                if total > scalar(0.0):
                    scalars[2] = scalars[0] / total
                else:
                    scalars[4] = scalar(1.0)
        elif stage == UPDATE:  # x += alpha p, r -= alpha q until done; thread 0 counts (per dof)
            if not done:
                alpha = scalars[2]
                work.x[t] = work.x[t] + alpha * work.p[t]
                work.r[t] = work.r[t] - alpha * work.q[t]
                if t == 0:
                    scalars[5] = scalars[5] + scalar(1.0)
        elif stage == NEXT_SUM:  # beta = new r^T z / old; done at the stop (one thread)
            total = partial_sum(work)
            if not done:
                scalars[3] = total / scalars[0]
                scalars[0] = total
                if not total > scalars[1]:
                    scalars[4] = scalar(1.0)
        elif stage == DIRECTION:  # p = z + beta p (per dof)
            work.p[t] = work.z[t] + scalars[3] * work.p[t]

    return stage_pass


def pcg_launches(semi: "FabricSemiImplicit", dt: float, max_iterations: int | None = None,
                 check_interval: int = 1) -> int:
    """x = A^-1 rhs of the system last assembled in `semi.work`, by PCG in the launch-per-stage
    layout (`stage_kernel`): 7 launches per iteration (8 where the planes move), the done flag
    read back every `check_interval` iterations (after done, no launch changes x, r or the
    count: the flag freezes them). Returns the iterations."""
    kernel, work, device, scalar = stage_kernel(semi.scalar), semi.work, semi.device, semi.scalar
    dofs, nodes = 2 * semi.arrays.nodes, semi.arrays.nodes
    yarns = work.partial.shape[0]
    max_iterations = dofs if max_iterations is None else max_iterations
    scalars = wp.zeros(6, dtype=scalar, device=device)
    dt2, tolerance = scalar(dt * dt), scalar(semi.cg_tolerance)

    def launch(stage, dim):
        wp.launch(kernel, dim=dim, device=device,
                  inputs=[semi.fabric, work, dt2, tolerance, scalars, stage])
    for stage, dim in ((START, dofs), (PRECONDITION, yarns), (FIRST_SUM, 1),
                       (COPY_DIRECTION, dofs)):
        launch(stage, dim)
    planes = ((BOUNDARY, 1),) if semi.arrays.plane_nodes.size else ()
    for launched in range(max_iterations):
        if launched % check_interval == 0 and scalars.numpy()[4] != 0.0:
            break
        for stage, dim in (*planes, (PRODUCT, nodes), (CURVATURE, yarns), (STEP_LENGTH, 1), (UPDATE, dofs),
                           (PRECONDITION, yarns), (NEXT_SUM, 1), (DIRECTION, dofs)):
            launch(stage, dim)
    return int(scalars.numpy()[5])


CROSSINGS, BUILD, VELOCITY, BOUNDARY_SUMS, RHS, MOVE, UNDO, MERIT, MERIT_SUM, TRIAL, SCALE = \
    range(11)
"""The stages of `step_stage_kernel`."""


@functools.cache
def step_stage_kernel(scalar):
    """The per-step layout's stages of a time step outside CG (one kernel, its stage chosen per
    launch): the crossing blocks (a thread per crossing), the yarn systems (per yarn), the
    velocities as flat dofs (per dof), the planes' sums of them and the tied dofs'
    preconditioner (one thread), the right side (per node), the move and its undoing (per
    node), a shortened step's positions and velocities (per node), the per-yarn merit and
    residual (per yarn) and their total (one thread, into sums = (residual, f^T M^-1 f))."""
    vec = VECTORS[scalar]
    Fabric, Work = fabric_arrays.struct(scalar), work_struct(scalar)
    ops, force_ops = functions(scalar), fabric_forces.functions(scalar, True)

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def step_pass(fabric: Fabric, work: Work, mass: wp.array(dtype=scalar),
                  anchors: wp.array(dtype=vec), pos: wp.array(dtype=vec), vel: wp.array(dtype=vec),
                  force: wp.array(dtype=vec), contact: wp.array(dtype=scalar), dt: scalar,
                  damping: scalar, sums: wp.array(dtype=scalar), stage: int, secant: int):
        t = wp.tid()
        if stage == CROSSINGS:
            ops.crossing_blocks(t, pos, fabric, anchors, contact, work,
                                force_ops.plane_shift(pos, fabric), secant)
        elif stage == BUILD:
            work.failed[t] = ops.build_yarn(t, pos, mass, fabric, work, dt, damping, 1)
        elif stage == VELOCITY:
            ops.velocity_dofs(t, vel, work)
        elif stage == BOUNDARY_SUMS:
            ops.boundary_sums(work.x, fabric, work)
            ops.tie_diagonals(fabric, work, dt * dt)
        elif stage == RHS:
            ops.rhs_node(t, vel, force, mass, fabric, work, dt)
        elif stage == MOVE:
            ops.move_node(t, pos, vel, work, dt)
        elif stage == UNDO:
            ops.undo_node(t, pos, vel, work)
        elif stage == TRIAL:  # dt = the shortened length alpha dt
            ops.trial_node(t, pos, vel, work, dt)
        elif stage == SCALE:  # dt = alpha
            ops.scale_node(t, vel, dt)
        elif stage == MERIT:
            value = ops.yarn_merit(t, force, mass, fabric, work)
            work.largest[t] = value[0]
            work.partial[t] = value[1]
        elif stage == MERIT_SUM:
            value = ops.merit_total(work)
            sums[0] = value[0]
            sums[1] = value[1]

    return step_pass


@dataclass
class SemiOutcome:
    """What a semi-implicit relaxation reached."""

    status: int
    """A `dynfab.kernels.status` code."""
    steps: int
    """Time steps taken (rejected ones included)."""
    residual: float
    """max |f| over the free dofs at the final positions [N]."""
    cg_iterations: int = 0
    """CG iterations over all the steps."""
    rejected: int = 0
    """Steps undone by the time step rule."""
    shortened: int = 0
    """Steps accepted at a fraction alpha < 1 of their length (the line search)."""
    backtracks: int = 0
    """Force evaluations at shortened lengths (one per halving)."""


class FabricSemiImplicit(PatchRelaxation):
    """Semi-implicit relaxation of one patch on one device (docs/model.md sections 5, 10); the
    interface of `fabric_explicit.FabricExplicit` (relax, return_map)."""

    def __init__(self, arrays: fabric_arrays.PatchArrays, *, device: str = "cpu",
                 layout: str | None = None, scalar=wp.float64, coefficient: float = 0.0,
                 dt: float = 1.0, cg_tolerance: float = CG_TOLERANCE, rule: str = "line_search"):
        if layout is None:
            layout = fabric_explicit.default_layout(device)
        if layout not in fabric_explicit.LAYOUTS:
            raise ValueError(f"layout {layout!r} unknown")
        if rule not in RULES:
            raise ValueError(f"time step rule {rule!r} unknown; one of {tuple(RULES)}")
        self.backtracks = RULES[rule]
        self.secant = int(rule != "halving" and arrays.plane_nodes.size > 0)
        """1: sliding crossings' friction blocks are the secant F_T/|s| I (module docstring)."""
        self._allocate(arrays, device, layout, scalar, dt)
        self.first_chunk = FIRST_CHUNK
        self.coefficient, self.cg_tolerance = coefficient, cg_tolerance
        self.work = allocate(arrays, scalar, device)

    def _run(self, pos, load, tolerance, max_steps):
        relax = self._persistent if self.layout == "persistent" else self._per_step
        return pos, relax(pos, load, tolerance, max_steps)

    def _persistent(self, pos, load, tolerance, max_steps) -> SemiOutcome:
        """The time loop in the kernel, launched for a bounded chunk of steps at a time
        (`PatchRelaxation.chunks`), the same bits as one launch."""
        code = wp.zeros(6, dtype=wp.int32, device=self.device)
        residual = wp.zeros(1, dtype=self.scalar, device=self.device)
        carry = wp.zeros(4, dtype=self.scalar, device=self.device)
        counters = wp.zeros(5, dtype=wp.int32, device=self.device)
        for first, stop_at in self.chunks(max_steps):
            wp.launch(relaxation_kernel(self.scalar), dim=1, device=self.device,
                      inputs=[self.fabric, self.work, self.mass, load, self.anchors,
                              self.scalar(self.dt), self.scalar(self.coefficient),
                              self.scalar(tolerance), self.scalar(self.cg_tolerance),
                              int(max_steps), first, stop_at, carry, counters, self.backtracks,
                              self.secant, pos, self.vel, self.force, self.contact,
                              self.friction, code, residual])
            status_code, steps, iterations, rejected, shortened, trials = \
                (int(v) for v in code.numpy())
            outcome = SemiOutcome(status_code, steps, float(residual.numpy()[0]), iterations,
                                  rejected, shortened, trials)
            if status_code != status.RUNNING:
                return outcome
            self._report(steps, outcome.residual)
        raise AssertionError("the last chunk ends at max_steps")

    def _per_step(self, pos, load, tolerance, max_steps) -> SemiOutcome:
        """The persistent kernel's time loop driven from Python, a launch per stage (threads
        per crossing, node and yarn; `step_stage_kernel`, `pcg_launches`), the decisions on
        values read back once or twice a step: the same arithmetic in the same order."""
        a, device, scalar = self.arrays, self.device, self.scalar
        passes = fabric_forces.kernels(scalar, True)
        stage_pass = step_stage_kernel(scalar)
        yarns = self.work.partial.shape[0]
        sums = wp.zeros(2, dtype=scalar, device=device)
        damping = scalar(self.coefficient)

        def stage(which, dim, dt=0.0):
            wp.launch(stage_pass, dim=dim, device=device,
                      inputs=[self.fabric, self.work, self.mass, self.anchors, pos, self.vel,
                              self.force, self.contact, scalar(dt), damping, sums, which,
                              self.secant])

        def evaluate():
            wp.launch(passes.crossing_pass, dim=a.crossings, device=device,
                      inputs=[pos, self.fabric, self.anchors, self.contact, self.friction])
            wp.launch(passes.node_pass, dim=a.nodes, device=device,
                      inputs=[pos, self.fabric, self.contact, self.friction, load, self.force])
            stage(MERIT, yarns)
            stage(MERIT_SUM, 1)
            return (float(v) for v in sums.numpy())
        dt = float(scalar(self.dt))
        residual, merit = evaluate()
        best, since_best, iterations, rejected = residual, 0, 0, 0
        shortened, trials = 0, 0
        code, steps = status.MAX_STEPS, 0
        for step in range(max_steps + 1):
            if not (np.isfinite(residual) and np.isfinite(merit)):
                code = status.NON_FINITE
                break
            if residual <= tolerance:
                code = status.CONVERGED
                break
            if step == max_steps:
                break
            if step >= STALL_MIN_STEPS and 2 * since_best > step:
                code = status.NO_PROGRESS
                break
            stage(CROSSINGS, a.crossings)
            for _ in range(MAX_REFACTORISATIONS):
                stage(BUILD, yarns, dt)
                if (self.work.failed.numpy() < 0).all():
                    break
                dt *= DT_SHRINK
            else:
                code = status.NOT_POSITIVE_DEFINITE
                break
            stage(VELOCITY, 2 * a.nodes)
            stage(BOUNDARY_SUMS, 1, dt)
            stage(RHS, a.nodes, dt)
            iterations += pcg_launches(self, dt, 2 * a.nodes)
            stage(MOVE, a.nodes, dt)
            new_residual, new_merit = evaluate()
            alpha = 1.0
            for _ in range(self.backtracks):
                if new_merit < merit:
                    break
                alpha *= 0.5
                trials += 1
                stage(TRIAL, a.nodes, alpha * dt)
                new_residual, new_merit = evaluate()
            if new_merit < merit:
                merit, residual = new_merit, new_residual
                if alpha < 1.0:
                    shortened += 1
                    stage(SCALE, a.nodes, alpha)
                else:
                    dt = min(dt * DT_GROWTH, DT_MAX)
            else:
                rejected += 1
                dt *= DT_SHRINK
                stage(UNDO, a.nodes)
                residual, _ = evaluate()
            if residual < best:
                best, since_best = residual, 0
            else:
                since_best += 1
            steps = step + 1
            self._report_now(steps, residual)
        return SemiOutcome(code, steps, residual, iterations, rejected, shortened, trials)

    def system(self, positions, external, anchors, velocities=None, *, dt: float = 1.0,
               definite: bool = True, solve: bool = False, masses: np.ndarray | None = None,
               max_iterations: int | None = None, assemble: bool = True, secant: bool = False):
        """Assemble (and with `solve`, PCG-solve) one step's system at `positions` (tests,
        benchmark), with `secant` the sliding crossings' secant blocks. Returns (bad pivot or
        -1, CG iterations)."""
        n = self.arrays.nodes
        mass = self.mass if masses is None else self._array(masses, self.scalar)
        velocities = np.zeros((n, 2)) if velocities is None else velocities
        self.anchors = self._array(anchors, self.vec)
        self._system_inputs = [self.fabric, self.work, mass, self._array(external, self.vec),
                               self.anchors, self._array(positions, self.vec),
                               self._array(velocities, self.vec), self.force, self.contact,
                               self.friction, self.scalar(dt), self.scalar(self.coefficient),
                               int(definite), int(secant)]
        return self._launch_system(assemble, solve, False, 2 * n if max_iterations is None
                                   else max_iterations)

    def _launch_system(self, assemble: bool, solve: bool, apply: bool, max_iterations: int):
        code = wp.zeros(2, dtype=wp.int32, device=self.device)
        wp.launch(system_kernel(self.scalar), dim=1, device=self.device,
                  inputs=[*self._system_inputs, int(assemble), int(solve), int(apply),
                          self.scalar(self.cg_tolerance), int(max_iterations), code])
        bad, iterations = (int(v) for v in code.numpy())
        return bad, iterations

    def dense(self, index: np.ndarray) -> np.ndarray:
        """The last assembled A on the unknowns (U, U), column u the kernels' product A T e_u
        read at u's first dof (tests). `index` (2n,): each dof's unknown, -1 where held, a
        tied family's dofs sharing one (`dynfab.fabric.assembly.Pattern.index`)."""
        index = np.asarray(index)
        unknowns = int(index.max()) + 1
        first = np.array([np.flatnonzero(index == u)[0] for u in range(unknowns)])
        A = np.zeros((unknowns, unknowns))
        for u in range(unknowns):
            self.work.p.assign((index == u).astype(self.dtype))
            self._launch_system(False, False, True, 0)
            A[:, u] = self.work.q.numpy()[first]
        return A
