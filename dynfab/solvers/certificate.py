"""Certificate of a converged load step: stable minimum or saddle, and its error bound
(docs/model.md section 6), for every model and solver.

One certificate, two routes to it, one record (`StepStability`: stable, buckled,
lowest_eigenvalue, lowest_eigenvalue_error, error_estimate) and one accuracy check
(`check_accuracy`):

- the banded route, where the chains are independent (the one-yarn model): an unpivoted
  LDL^T per chain, below;
- the sparse route, where they are tied (the woven fabric): SuperLU's factorisation of the
  whole patch (`certify_patch`, `escape_patch`, with `dynfab.model.fabric.inertia`; at the end of
  this module, and docs/model.md, "Stability and accuracy of a converged step").

On the banded route both solvers call `certify` on every converged yarn, in float64 on the
host:

- The matrix (`certificate_matrix`): the symmetric Hessian of V plus the Huber
  friction terms with F_T frozen at the state's values (not the coupled
  friction Jacobian, not the secant or a shifted matrix), fixed dofs
  constrained out. At a kink it takes the softer branch: a crossing whose
  contact force is within the step's residual counts as open (no contact
  tangent), a crossing whose trial friction force k_t |s| is within the
  residual of F_T counts as sliding (no Huber curvature along the slip).
  At that accuracy the state cannot tell the branches apart.
- The inertia (`dynfab.linalg.ldlt`): unpivoted LDL^T, negative pivots counted
  (Sylvester). A pivot within tau = 64 eps max|H_ii| of zero: H + tau I is
  factored instead (doubling tau while a pivot stays that small); all
  pivots positive then prove lambda_min > -tau. `stable` = no negative pivot.
- The lowest eigenvalue: on a stable state, shift-invert Lanczos with the
  factor (at most LANCZOS_STEPS solves, from a smooth start vector): the Ritz
  vector y of the largest Ritz value of H^-1 has a Rayleigh quotient
  lambda >= lambda_min and an eigen-residual r = ||H y - lambda y|| (|y| = 1),
  so an eigenvalue lies in [lambda - r, lambda], and (Kato-Temple) in
  [lambda - r^2 / gap, lambda], gap = lambda_2 - lambda estimated from the
  second Ritz value. One more LDL^T, of H - l I, without a negative pivot
  proves lambda_min >= l (Sylvester): tried with the Kato-Temple l, then
  with lambda - r. Reported: lambda, with lambda_min in [lambda - e, lambda]
  (e = `LOWEST_ERROR` = lambda - the proved l; where neither is proved,
  e = lambda + tau: only lambda_min > -tau is known). On an unstable state:
  bisection on the inertia of H - s I between Gershgorin's lower bound and
  the smallest Rayleigh quotient d_i / |v_i|^2 of the escape vectors, to
  1e-6 relative (`_bisect_lowest`: about 40 factorisations, only on a state
  reported unstable); `LOWEST_ERROR` is the bracket's width.
- The error bound: residual x est ||H^-1||_inf, the Hager-Higham estimate of
  `dynfab.linalg.ldlt.inverse_norm_1` (H symmetric: the 1- and inf-norms agree):
  |x - x*|_inf <= ||H^-1||_inf |f|_inf to first order, f the residual force.
  Infinite when H needed the shift tau to factor: singular to rounding, it
  bounds nothing (`check_accuracy` then stops the step).
- The escape (`escape`): from each negative pivot d_i, v = L^-T e_i has
  v^T H v = d_i < 0. Each v (scaled to max |v_i| = 1 m, its largest |z|
  component made positive) is tried with steps t = L 2^-k, k = 0..52, both
  signs, on V plus the Huber terms (F_T frozen at the saddle's values); the
  lowest energy found wins. Ties (within the rounding of the energy sum)
  keep the earlier candidate: the larger step, the + sign, the first pivot,
  so mirror branches of equal energy are chosen by the sign rule
  "largest |z| component of v positive", in both solvers. If no trial lowers
  the energy beyond rounding, the state is accepted as it is (unstable).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import scipy.sparse.linalg

from dynfab.model import assembly
from dynfab.linalg.banded import BANDWIDTH, band_add, band_matvec, constrain
from dynfab.errors import SolverError
from dynfab.model.terms.kinematics import physical_positions, terms_of, woven_plan
from dynfab.model.fabric import inertia
from dynfab.model.fabric import ordering as fabric_ordering
from dynfab.linalg.ldlt import (TINY_PIVOT, inverse_norm_1, ldlt_factor, ldlt_solve,
                                negative_direction)
from dynfab.scene import Static
from dynfab.model.structure import Structure, dim, grounded, sliding, tie_layout
from dynfab.model.terms import friction

EPS = np.finfo(np.float64).eps
SCALE_FLOOR = np.sqrt(EPS) / Static.accuracy
"""The least displacement scale of a step over the structure's length [-] (1.5e-7): at the
default accuracy (0.1) a step that barely moves is accepted with a position error bound up to
sqrt(eps) L (`StepStability.scale`; docs/model.md, "Stability and accuracy of a converged
step")."""
LANCZOS_STEPS = 20
"""Solves of shift-invert Lanczos for the lowest eigenvalue of a stable state, at most."""
LANCZOS_MEMORY = 20_000_000
"""Numbers the Lanczos basis may hold (160 MB): fewer steps on meshes above 1e6 dofs."""
LANCZOS_TOLERANCE = 1e-6
"""Lanczos stops once the top Ritz value of H^-1 has a residual below this times the
Rayleigh quotient of the start vector's inverse (relative, about)."""
MAX_CANDIDATES = 64
"""Negative pivots whose vectors `escape` tries (the most negative Rayleigh quotients are not
the best escapes: far past a buckling load the lowest mode releases the most energy)."""
MAX_ESCAPES = 12
"""Escapes per yarn (per patch, on the sparse route) and load step before a solver accepts
the state it has."""
ESCAPE_CANDIDATES = 16
"""The sparse route's escape directions per escape, at most: the lowest eigenvectors."""
STEP_HALVINGS = 53
"""Steps t = L 2^-k, k < STEP_HALVINGS, tried along each escape vector (down to rounding)."""
LANCZOS_VECTORS = 8
"""ARPACK's ncv for a stable state's lowest eigenpair (k = 1, shift-invert at 0): the Lanczos
basis filled before ARPACK first tests convergence, one solve with the factor per vector
(scipy's default, 20, costs 21 solves where 8 converge in fewer: docs/results.md, "The one
model against the code it replaced")."""
NEGATIVES, LOWEST, LOWEST_ERROR, INVERSE_NORM, SHIFT = range(5)
"""Fields of `certify`'s result array."""
CERTIFICATE_KEYS = ("stable", "buckled", "lowest_eigenvalue", "lowest_eigenvalue_error",
                    "error_estimate")
"""The record entries of the certificate (`StepStability.fields`), every model's."""


@numba.njit(cache=True)
def certificate_matrix(pos, yarn, anchors, fixed, residual, band):
    """band = the certificate's Hessian (module docstring), fixed dofs replaced by identity rows.

    Returns F_T per crossing [N], the frozen friction limits it used.
    """
    force, limit, tangent = assembly.contact_state_of(pos, yarn)
    assembly.hessian(pos, yarn, anchors, limit, tangent, False, band, False)
    for j in range(force.size):
        dof = 2 * yarn.crossing_node[j]
        if tangent[j] > 0.0 and force[j] <= residual:  # at g = 0: open
            band_add(band, dof + 1, dof + 1, -tangent[j])
        if yarn.active[friction.INDEX]:
            slip = pos[yarn.crossing_node[j], 0] - anchors[j]
            k_t = yarn.stick_stiffness
            if (not friction.is_sliding(slip, limit[j], k_t)
                    and k_t * abs(slip) >= limit[j] - residual):  # at the stick/slip kink: sliding
                band_add(band, dof, dof, -k_t)
    constrain(band, np.zeros(band.shape[0]), fixed)
    return limit


@numba.njit(cache=True)
def _canonical(v):
    """Scale v to max |v_i| = 1 and make its largest |z| component (odd dof) positive."""
    largest, at = 0.0, -1
    for i in range(v.size):
        largest = max(largest, abs(v[i]))
    for i in range(1, v.size, 2):
        if at < 0 or abs(v[i]) > abs(v[at]):
            at = i
    if at < 0 or v[at] == 0.0:
        for i in range(v.size):
            if at < 0 or abs(v[i]) > abs(v[at]):
                at = i
    sign = 1.0 if v[at] >= 0.0 else -1.0
    v *= sign / largest


@numba.njit(cache=True)
def _factor(band, matrix, free):
    """Factor the certificate matrix in place, shifted when a pivot is tiny; (negatives, shift)."""
    largest = 0.0
    for i in range(free.size):
        if free[i]:
            largest = max(largest, abs(matrix[i, BANDWIDTH]))
    tau = 64.0 * EPS * max(largest, 1e-300)
    shift = 0.0
    negatives = ldlt_factor(band, shift, tau)
    while negatives == TINY_PIVOT and shift < 1e6 * tau:
        shift = tau if shift == 0.0 else 2.0 * shift
        band[:, :] = matrix
        negatives = ldlt_factor(band, shift, 1e-3 * tau)
    return negatives, shift


@numba.njit(cache=True)
def _ritz_vectors(alpha, beta, used):
    """(eigenvalues ascending, eigenvectors as columns) of the Lanczos tridiagonal of order `used`."""
    tridiagonal = np.zeros((used, used))
    for j in range(used):
        tridiagonal[j, j] = alpha[j]
        if j + 1 < used:
            tridiagonal[j, j + 1] = tridiagonal[j + 1, j] = beta[j]
    return np.linalg.eigh(tridiagonal)


@numba.njit(cache=True)
def _no_eigenvalue_below(work, matrix, free, lower):
    """Whether `matrix` - lower I has no negative pivot, which proves lambda_min >= lower
    (Sylvester); its LDL^T overwrites `work`."""
    work[:, :] = matrix
    for i in range(free.size):
        if not free[i]:  # identity rows of fixed dofs: keep them out of the count
            work[i, BANDWIDTH] = lower + 1.0
    return ldlt_factor(work, -lower, 0.0) == 0


@numba.njit(cache=True)
def _lowest_eigenvalue(band, matrix, free, shift):
    """(estimate, error) of lambda_min of a positive definite `matrix` (module docstring).

    Shift-invert Lanczos with the factor of matrix + shift I, full reorthogonalisation,
    LANCZOS_STEPS solves at most: the largest Ritz value of the inverse gives the Ritz
    vector y, whose Rayleigh quotient lambda >= lambda_min and eigen-residual
    r = ||H y - lambda y|| (|y| = 1) put an eigenvalue in [lambda - r, lambda]. That it is
    the lowest is then proved by Sylvester: H - (lambda - r) I has no negative pivot.
    If not, the error is lambda + shift (lambda_min > -shift is all that is known).
    Overwrites `band` (the factor) with the proof's factorisation.
    """
    n = free.size
    steps = min(LANCZOS_STEPS, np.count_nonzero(free), max(6, LANCZOS_MEMORY // n))
    basis = np.zeros((steps, n))
    alpha, beta = np.zeros(steps), np.zeros(steps)
    q = np.zeros(n)
    for i in range(n):
        q[i] = 1.0 + i / n if free[i] else 0.0  # smooth, like the softest modes
    q /= np.sqrt(np.dot(q, q))
    used = 0
    ritz, vectors = np.zeros(1), np.zeros((1, 1))
    for j in range(steps):
        basis[j] = q
        used = j + 1
        w = q.copy()
        ldlt_solve(band, w)
        alpha[j] = np.dot(q, w)
        for m in range(j + 1):  # full reorthogonalisation
            w -= np.dot(basis[m], w) * basis[m]
        beta[j] = np.sqrt(np.dot(w, w))
        if j == steps - 1 or (j >= 5 and j % 3 == 2):
            ritz, vectors = _ritz_vectors(alpha, beta, used)
            # Ritz residual of the inverse: beta_j |last component of the top Ritz vector|
            if beta[j] * abs(vectors[used - 1, used - 1]) <= LANCZOS_TOLERANCE * abs(alpha[0]):
                break
        if beta[j] <= 1e-14 * abs(alpha[j]):
            break
        q = w / beta[j]
    if vectors.shape[0] != used:
        ritz, vectors = _ritz_vectors(alpha, beta, used)
    y = np.zeros(n)
    for j in range(used):
        y += vectors[j, used - 1] * basis[j]
    y /= np.sqrt(np.dot(y, y))
    hy = np.zeros(n)
    band_matvec(matrix, y, hy)
    value = np.dot(y, hy)
    hy -= value * y
    residual = np.sqrt(np.dot(hy, hy))
    # Lower bounds to prove, tightest first: Kato-Temple's value - r^2 / (lambda_2 - value)
    # with lambda_2 from the second Ritz value, then value - r.
    second = 1.0 / ritz[used - 2] if used > 1 and ritz[used - 2] > 0.0 else np.inf
    gap = second - value
    tight = value - max(residual * residual / gap, 64.0 * EPS * value) if gap > residual else -np.inf
    for lower in (tight, value - residual):
        if lower == -np.inf:
            continue
        if _no_eigenvalue_below(band, matrix, free, lower):  # the factor is no longer needed
            return value, value - lower
    return value, value + shift


@numba.njit(cache=True)
def _bisect_lowest(check, matrix, free, upper):
    """(estimate, error) of lambda_min < 0 of an indefinite `matrix` by bisection on inertia.

    lambda_min lies in [lower, upper]: `upper` is a Rayleigh quotient (>= lambda_min), the
    start of `lower` Gershgorin's bound. H - s I without a negative pivot proves
    lambda_min >= s, with one proves lambda_min < s (Sylvester). Bisection until the bracket
    is 1e-6 of |upper| wide (about 40 factorisations, only on a state reported unstable).
    `check` is work space of the matrix's shape.
    """
    lower = 0.0
    for i in range(free.size):
        if free[i]:
            row = matrix[i, BANDWIDTH]
            for m in range(2 * BANDWIDTH + 1):
                if m != BANDWIDTH:
                    row -= abs(matrix[i, m])
            lower = min(lower, row)
    for _ in range(200):
        if upper - lower <= 1e-6 * abs(upper):
            break
        middle = 0.5 * (lower + upper)
        if _no_eigenvalue_below(check, matrix, free, middle):
            lower = middle
        else:
            upper = middle
    return upper, upper - lower


@numba.njit(cache=True)
def certify(pos, yarn, anchors, fixed, residual, directions, result):
    """Certify one yarn's converged state; result (5,) = NEGATIVES, LOWEST, LOWEST_ERROR,
    INVERSE_NORM, SHIFT; on a saddle `directions` (MAX_CANDIDATES, dofs) holds the escape
    vectors (canonical, module docstring), the first `min(negatives, MAX_CANDIDATES)` rows.
    """
    n = pos.size
    band = np.zeros((n, 2 * BANDWIDTH + 1))
    certificate_matrix(pos, yarn, anchors, fixed, residual, band)
    matrix = band.copy()
    free = ~fixed
    negatives, shift = _factor(band, matrix, free)
    result[:] = np.nan
    result[NEGATIVES], result[SHIFT] = negatives, shift
    if negatives == TINY_PIVOT:  # NaN in the matrix
        return
    # A shifted factor bounds nothing: H itself is singular to within its rounding.
    result[INVERSE_NORM] = inverse_norm_1(band, free) if shift == 0.0 else np.inf
    # The last uses of the factor; then `band` is the work space of the inertia counts.
    if negatives == 0:
        result[LOWEST], result[LOWEST_ERROR] = _lowest_eigenvalue(band, matrix, free, shift)
    else:
        found, lowest = 0, np.inf
        for i in range(n):
            if band[i, BANDWIDTH] < 0.0 and found < directions.shape[0]:
                v = directions[found]
                negative_direction(band, i, v)
                lowest = min(lowest, band[i, BANDWIDTH] / np.dot(v, v) - shift)
                _canonical(v)
                found += 1
        result[LOWEST], result[LOWEST_ERROR] = _bisect_lowest(band, matrix, free,
                                                              min(lowest, 0.0))


@numba.njit(cache=True)
def _energy(pos, yarn, P, anchors, limit, terms):
    assembly.energies(pos, yarn, P, anchors, limit, terms)
    return terms.sum()


@numba.njit(cache=True)
def escape(pos, yarn, P, anchors, directions, count, out):
    """out = the trial of lowest V + H (F_T frozen) along the first `count` escape vectors
    (module docstring); returns the energy drop [J] (0 when none lowers V + H beyond rounding)."""
    _, limit, _ = assembly.contact_state_of(pos, yarn)
    terms = assembly.energy_vector()
    e0 = _energy(pos, yarn, P, anchors, limit, terms)
    rounding = 64.0 * EPS * (np.abs(terms).sum() + abs(P) * abs(pos[-1, 0]))
    length = abs(yarn.rest_position[-1, 0] - yarn.rest_position[0, 0])
    trial = np.empty_like(pos)
    best = e0 - rounding
    out[:, :] = pos
    for candidate in range(count):
        d = directions[candidate].reshape(pos.shape)
        t = length
        for _ in range(STEP_HALVINGS):
            for sign in (1.0, -1.0):
                trial[:, :] = pos + (sign * t) * d
                e = _energy(trial, yarn, P, anchors, limit, terms)
                if e < best - rounding:
                    best = e
                    out[:, :] = trial
            t *= 0.5
    drop = e0 - best
    return drop if drop > rounding else 0.0


def certify_yarn(pos, yarn, anchors, fixed, residual):
    """`certify` for one yarn: (result (5,), escape vectors)."""
    directions = np.zeros((MAX_CANDIDATES, pos.size))
    result = np.zeros(5)
    certify(pos, yarn, anchors, fixed, float(residual), directions, result)
    return result, directions


def escape_yarn(pos, yarn, P, anchors, result, directions):
    """The escaped positions of one yarn (a new array), or None when no direction lowers V + H."""
    count = int(min(result[NEGATIVES], MAX_CANDIDATES))
    out = np.empty_like(pos)
    drop = escape(pos, yarn, float(P), anchors, directions, count, out)
    return out if drop > 0.0 else None


def displacement_scale(positions, rest_positions):
    """The displacement scale of a step [m]: max |r - r0| over the yarn's nodes and coordinates."""
    return float(np.max(np.abs(positions - rest_positions)))


SINGULAR_ADVICE = "use a coarser mesh or softer data"
"""What a singular stiffness matrix's message advises, unless the model knows better (its
`singular_advice`: a shear specimen without friction)."""


def check_accuracy(where: str, error_estimate: float, scale: float, residual: float,
                   tolerance: float, accuracy: float, at_floor: bool, precision: str,
                   key: str, singular_shift: float = 0.0,
                   singular_advice: str = SINGULAR_ADVICE) -> None:
    """SolverError (one line) when the error bound is not small against the step's displacements.

    Accepted: error_estimate <= accuracy x max(displacement, SCALE_FLOOR L), checked by the
    caller through `scale` (already floored, `StepStability.scale`). The message starts with `where`
    (the one-yarn model: "yarn k"; a fabric: the patch and the yarn where the bound is
    largest, `patch_location`), says what the residual implies and what to change
    (docs/model.md section 6, docs/model.md "Stability and accuracy of a converged step").
    An infinite estimate means the matrix needed the shift `singular_shift` [N/m] to factor.
    Every solver of every model calls it.
    """
    if error_estimate <= accuracy * scale:
        return
    if np.isinf(error_estimate):
        raise SolverError(
            f"{where}: the stiffness matrix is singular to rounding (a pivot within "
            f"{singular_shift:.3g} N/m of zero, 64 eps of its largest diagonal entry), so the "
            f"residual {residual:.3g} N bounds no position error: {singular_advice}")
    inverse_norm = error_estimate / residual if residual > 0 else np.inf
    needed = accuracy * scale / inverse_norm
    if at_floor or residual > tolerance:
        change = ("use float64" if precision == "float32" else
                  "use a coarser mesh or softer data (the rounding floor grows with N and stiffness)")
        reached = f"the residual stopped at {residual:.3g} N (rounding floor of {precision})"
    else:
        change = (f"tighten the tolerance to below {needed:.2g} N" if precision == "float64" else
                  f"use float64, or a tolerance below {needed:.2g} N if float32 reaches it")
        reached = f"the residual {residual:.3g} N (tolerance {tolerance:.3g} N)"
    raise SolverError(
        f"{where}: {reached} leaves a position error up to {error_estimate:.3g} m "
        f"(residual x ||H^-1||_inf = {inverse_norm:.3g} m/N), above {key} = {accuracy:g} of the "
        f"step's largest displacement {scale:.3g} m: {change}, or loosen {key}")


class StepStability:
    """The certificate fields of one load step's record, filled certified unit by unit (the
    one-yarn model's yarns; a fabric's one patch), for every solver of every model.

    `stable` (no negative pivot), `buckled` (an escape left a saddle in this step),
    `lowest_eigenvalue` [N/m] (the lowest eigenvalue of the frozen-F_T Hessian on the free
    dofs), `lowest_eigenvalue_error` [N/m] (lambda_min lies in [lowest_eigenvalue - error,
    lowest_eigenvalue]) and `error_estimate` [m] (residual x est ||H^-1||_inf).
    """

    def __init__(self, units: int):
        self.stable = np.zeros(units, np.bool_)
        self.buckled = np.zeros(units, np.bool_)
        self.lowest_eigenvalue = np.full(units, np.nan)
        self.lowest_eigenvalue_error = np.full(units, np.nan)
        self.error_estimate = np.full(units, np.nan)
        self.shift = np.zeros(units)

    def record(self, k: int, result: np.ndarray, residual: float) -> None:
        """Unit k's certificate `result` (`certify`, `PatchCertificate.result`) at its final
        residual [N]."""
        self.stable[k] = result[NEGATIVES] == 0
        self.lowest_eigenvalue[k] = result[LOWEST]
        self.lowest_eigenvalue_error[k] = result[LOWEST_ERROR]
        self.shift[k] = result[SHIFT]
        self.error_estimate[k] = residual * result[INVERSE_NORM] if residual > 0 else 0.0

    @staticmethod
    def scale(positions: np.ndarray, rest_positions: np.ndarray,
              length: float | None = None) -> float:
        """The step's displacement scale [m]: max |r - r0| over nodes and coordinates, at least
        SCALE_FLOOR L, so that at the default accuracy a step that barely moves is accepted
        with a position error bound up to sqrt(eps) L, half the digits of float64 at the
        structure's size (docs/model.md, "Stability and accuracy of a converged step");
        L = `length`, else the extent of `rest_positions` along coordinate 0 (a yarn's)."""
        if length is None:
            length = abs(rest_positions[-1, 0] - rest_positions[0, 0])
        return max(displacement_scale(positions, rest_positions), SCALE_FLOOR * length)

    def fields(self) -> dict:
        """The record entries (`steps/<name>` of the result file), arrays (units,)."""
        return {name: getattr(self, name).copy() for name in CERTIFICATE_KEYS}


# --------------------------------------------------------------------------
# The sparse route: chains tied to each other (the woven fabric, docs/model.md section 10).


@dataclass
class PatchCertificate:
    """The certificate of a patch's converged state (`certify_patch`)."""

    result: np.ndarray
    """(5,): NEGATIVES, LOWEST, LOWEST_ERROR, INVERSE_NORM, SHIFT, as `certify`'s."""
    nearest: float
    """The eigenvalue nearest zero [N/m] (ARPACK shift-invert at 0; NaN if ARPACK failed):
    on a saddle, where the escape's search for a shift below the spectrum starts."""
    vectors: np.ndarray | None
    """On a saddle, the lowest eigenvectors on the unknowns (the escape's candidates, at
    most ESCAPE_CANDIDATES, `dynfab.model.fabric.inertia.lowest_eigenvectors`); else None."""
    worst: int
    """The unknown whose row of H^-1 has the largest 1-norm (where the error bound is
    largest; Hager-Higham's maximising column, H symmetric), -1 if none."""

    @property
    def negatives(self) -> int:
        return int(self.result[NEGATIVES])


def certify_patch(model, pos, anchors, limit) -> PatchCertificate:
    """Certify a patch's converged state (docs/model.md section 6, "Stability and accuracy of
    a converged step"). `model` is the fabric's (`dynfab.model.fabric.model.FabricModel`: its
    structure, its Hessian on the unknowns, F_T = `limit` frozen, and their pattern).

    - The inertia: SuperLU's symmetric-mode pivots in the pattern's nested-dissection order
      (`dynfab.model.fabric.inertia.sparse_factor`), else the Schur (or dense) route with a
      rounding-level shift where a pivot vanishes (`dynfab.model.fabric.inertia.inertia`).
    - The lowest eigenvalue and its bracket (`_bracket`): on a stable state the Ritz pair of
      ARPACK's shift-invert Lanczos at 0 with that factor; on a saddle the lowest of the
      shift-invert Lanczos below the spectrum that the escape runs
      (`dynfab.model.fabric.inertia.lowest_eigenvectors`).
    - est ||H^-1||_inf (`_inverse_norm`): Hager-Higham (scipy's onenormest and Higham's
      alternating vector) with the factor's solves; infinite where the count needed a shift
      (H singular to rounding) or no factorisation of H exists.
    """
    f = model.structure
    H = model.hessian(pos, anchors, limit)
    n = H.shape[0]
    scale = float(np.abs(H.diagonal()).max()) if n else 0.0
    order = fabric_ordering.fabric_order(f, model.pattern)
    counted, solve = inertia.sparse_factor(H, 0.0, scale, order)
    if counted is None:
        counted = inertia.inertia(model, pos, anchors, limit)
        solve = inertia.shifted_solve(H, 0.0, order) if counted.shift == 0.0 else None
    result = np.full(5, np.nan)
    result[NEGATIVES], result[SHIFT] = counted.negatives, counted.shift
    norm, worst = _inverse_norm(solve, n) if solve is not None and counted.shift == 0.0 \
        else (np.inf, -1)
    result[INVERSE_NORM] = norm
    nearest, vectors = np.nan, None
    if n == 0:  # nothing left to move (every dof held): no eigenvalue
        pass
    elif counted.negatives == 0:
        start = inertia.start_vector(n)
        inverse = None if solve is None else scipy.sparse.linalg.LinearOperator(
            H.shape, matvec=solve, dtype=float)
        try:
            values, ritz = scipy.sparse.linalg.eigsh(H, k=1, sigma=0.0, which="LM",
                                                     tol=inertia.EIGEN_TOL, OPinv=inverse,
                                                     v0=start, ncv=min(LANCZOS_VECTORS, n))
            nearest = float(values[0])
            result[LOWEST], result[LOWEST_ERROR] = _bracket(H, ritz[:, 0], scale, order,
                                                            -counted.shift)
        except (RuntimeError, scipy.sparse.linalg.ArpackNoConvergence):
            pass  # no eigenvalue: the fields stay NaN
    else:
        nearest = inertia.nearest_eigenvalue(H)
        count = min(counted.negatives, ESCAPE_CANDIDATES, n - 1)
        _, vectors, bound = inertia.lowest_eigenvectors(model, pos, anchors, limit, count, nearest)
        result[LOWEST], result[LOWEST_ERROR] = _bracket(H, vectors[:, 0], scale, order, bound)
    return PatchCertificate(result, nearest, vectors, worst)


def _bracket(H, y, scale, order, proved) -> tuple[float, float]:
    """(lambda, e): lambda_min of H lies in [lambda - e, lambda] (docs/model.md section 6).

    lambda = y^T A y / y^T y (A = (H + H^T)/2, the matrix the inertia counts), a Rayleigh
    quotient, so lambda >= lambda_min; r = |A y - lambda y| (|y| = 1) puts an eigenvalue in
    [lambda - r, lambda]. That it is the lowest is proved by Sylvester: A - l I without a
    negative pivot (SuperLU's symmetric-mode count, `inertia.sparse_inertia`), at
    l = lambda - r - 1e3 eps max|H_ii| (a margin that keeps the count's smallest pivot
    above its guard, 64 eps max|H_ii|, where lambda - r is within rounding of lambda_min).
    Where that count is refused or finds a negative, l is `proved`, the lower bound the
    certificate's inertia count already proves (0 less its rounding shift on a stable
    state, the escape's shift below the spectrum on a saddle)."""
    y = y / np.linalg.norm(y)
    Ay = 0.5 * (H @ y + H.T @ y)
    value = float(y @ Ay)
    residual = float(np.linalg.norm(Ay - value * y))
    lower = value - residual - 1e3 * EPS * scale
    counted = inertia.sparse_inertia(H, -lower, scale, order)
    if counted is None or counted.negatives > 0:
        lower = proved
    return value, value - lower


def _inverse_norm(solve, n: int) -> tuple[float, int]:
    """(est ||H^-1||_inf [m/N], the unknown whose row has the largest 1-norm) with the
    factor's solves, H symmetric (H^-T = H^-1; the 1- and inf-norms agree): Hager's estimate
    (scipy.sparse.linalg.onenormest with one column, at most 5 sweeps of two solves;
    deterministic) and Higham's alternating vector x_i = (-1)^i (1 + i / (n - 1)), whose
    2 |H^-1 x|_1 / (3 n) is taken if larger, as the one-yarn model's `inverse_norm_1`. A
    lower bound of the norm, in practice within a factor 3. (Two columns, scipy's default,
    draw their second from numpy's global generator and cost as much again in its checks
    for parallel columns as in solves.)"""
    if n == 0:
        return 0.0, -1
    inverse = scipy.sparse.linalg.LinearOperator((n, n), matvec=solve, rmatvec=solve,
                                                 matmat=solve, rmatmat=solve, dtype=float)
    estimate, v = scipy.sparse.linalg.onenormest(inverse, t=1, compute_v=True)
    i = np.arange(n)
    alternating = np.where(i % 2 == 0, 1.0, -1.0) * (1.0 + i / max(n - 1, 1))
    estimate = max(float(estimate), 2.0 * np.abs(solve(alternating)).sum() / (3.0 * n))
    return estimate, int(np.argmax(np.abs(v)))


def longest_chain(structure: Structure) -> float:
    """The largest as-woven chord of a chain seen from above [m] (a fabric's longer family)."""
    plan = woven_plan(structure)
    extent = plan[structure.load_node] - plan[structure.chain_start[:-1]]
    return float(np.max(np.hypot(extent[:, 0], extent[:, 1])))


def escape_patch(model, pos, P, anchors, limit, checked: PatchCertificate):
    """The sparse route's escape from a saddle (docs/model.md section 6): the positions of
    lowest V + H (F_T = `limit` frozen) along the certificate's lowest eigenvectors, steps
    +-t v with t from the longest chain's length halving STEP_HALVINGS times, a trial taken
    only when lower by more than the energy's rounding (64 eps times the sum of |terms| and
    the positions' rounding scale, `dynfab.model.fabric.assembly.rounding_scale`); ties keep the
    larger step, the + sign, the lower eigenvector. None when no trial lowers the energy.
    P: the end loads (Y,) [N]."""
    f = model.structure
    energy_terms = terms_of(f)
    terms = np.zeros(len(energy_terms.TERMS))
    e0 = energy_terms.total_energy(pos, f, P, anchors, limit, terms)
    rounding = 64.0 * EPS * (np.abs(terms).sum() + energy_terms.rounding_scale(pos, f, P, limit))
    length = longest_chain(f)
    best, best_pos = e0 - rounding, None
    for k in range(checked.vectors.shape[1]):
        d = model.pattern.expand(checked.vectors[:, k]).reshape(pos.shape)
        t = length
        for _ in range(STEP_HALVINGS):
            for sign in (1.0, -1.0):
                trial = pos + (sign * t) * d
                e = energy_terms.total_energy(trial, f, P, anchors, limit, terms)
                if e < best - rounding:
                    best, best_pos = e, trial
            t *= 0.5
    return best_pos


def check_patch_accuracy(model, checked: PatchCertificate, stability: StepStability, pos,
                         residual: float, tolerance: float, accuracy: float, at_floor: bool,
                         key: str) -> None:
    """`check_accuracy` for a patch whose certificate `stability` recorded (unit 0) at
    positions `pos` (nodes, 2) [m]: the scale is the largest displacement of any node, at
    least SCALE_FLOOR times the longest chain (`StepStability.scale`); the message names the yarn and node where the
    bound is largest (`patch_location`); float64."""
    f = model.structure
    scale = StepStability.scale(physical_positions(f, pos), f.rest_position, longest_chain(f))
    if stability.error_estimate[0] <= accuracy * scale:
        return
    name = model.group_name(None)
    where = (name if checked.worst < 0 else
             f"{name} ({patch_location(model, checked.worst)}: where the bound is largest)")
    advice = getattr(getattr(model, "model", None), "singular_advice", None) or SINGULAR_ADVICE
    check_accuracy(where, stability.error_estimate[0], scale, residual, tolerance, accuracy,
                   at_floor, "float64", key, stability.shift[0], advice)


def patch_location(model, unknown: int) -> str:
    """Where unknown `unknown` of the patch lies, in words: "warp k, node i" (1-based k, the
    node counted from 0 along the yarn), the first of its dofs (a periodic cell's tied cell
    length is one unknown of several yarns)."""
    f = model.structure
    dof = int(np.flatnonzero(model.pattern.index == unknown)[0])
    node = dof // f.rest_position.shape[1]
    y = int(np.searchsorted(f.chain_start, node, side="right") - 1)
    return f"{model.yarn_name(y)}, node {node - int(f.chain_start[y])}"


# --------------------------------------------------------------------------
# One certificate for a step of any structure: the route chosen by the structure.


class GroupLayout:
    """What the certificate of a model's steps reads of its structure, worked out once per model
    (`certify_groups`): its groups (`RunModel.groups`, each a contiguous range of chains), the
    route its structure allows (`dynfab.model.structure.grounded`, crossings that slide apart:
    banded per chain, one chain per
    group; else the sparse route of the whole structure, one group), each group's nodes and
    longest chain, and on the banded route each chain's ties, held dofs and Yarn view (the
    model's `yarns`)."""

    def __init__(self, model):
        s = self.structure = model.structure
        self.model = model
        self.groups = [np.asarray(chains) for chains in model.groups]
        self.banded = grounded(s) and not sliding(s)  # sliding: the sparse term set
        if self.banded and any(chains.size != 1 for chains in self.groups):
            raise ValueError("the banded certificate takes one chain per group")
        if not self.banded and len(self.groups) != 1:
            raise ValueError("the sparse certificate takes the whole structure as one group")
        self.nodes = [slice(int(s.chain_start[chains[0]]), int(s.chain_start[chains[-1] + 1]))
                      for chains in self.groups]
        """Each group's nodes (its chains are contiguous)."""
        first, last = s.chain_start[:-1], s.load_node
        extent = s.rest_position[last, 0] - s.rest_position[first, 0]
        self.lengths = [float(np.max(extent[chains])) for chains in self.groups]
        """Each group's longest chain as woven [m]."""
        self.chains = []
        """On the banded route, per group: (its chain's ties, held dofs, Yarn view)."""
        if self.banded:
            d = dim(s)
            for k, chains in enumerate(self.groups):
                ties, _ = tie_layout(s, int(chains[0]))
                nodes = self.nodes[k]
                self.chains.append((ties, s.fixed[d * nodes.start:d * nodes.stop],
                                    model.yarns[int(chains[0])]))


class GroupCertificates:
    """The certificate of every group of a converged load step (`certify_groups`), for any
    model (`dynfab.solvers.contract.RunModel`: its `groups`, `group_name`), on the route its
    structure allows (`GroupLayout`): banded per chain where the chains are independent
    (`certify_yarn` on the model's `yarns` views, one chain per group), the sparse route of the
    whole patch otherwise (`certify_patch`: one group).

    `stability` holds the record's fields (`StepStability`, one unit per group); `escaped` gives
    the positions each group on a saddle moves to (`escape_yarn`, `escape_patch`); `check` is
    the accuracy check (`check_accuracy`) of every group; `scales` the displacement scales it
    holds the error bounds to.
    """

    def __init__(self, layout: GroupLayout, positions, anchors, limit, loads, residuals):
        self.layout, self.model = layout, layout.model
        self.positions = np.asarray(positions, float)
        self.anchors, self.limit = np.asarray(anchors, float), np.asarray(limit, float)
        self.loads = np.asarray(loads, float)
        self.residuals = np.asarray(residuals, float)
        count = len(layout.groups)
        self.stability = StepStability(count)
        self.checks = [self._certify(k) for k in range(count)]
        self.results = [check[0] if layout.banded else check.result for check in self.checks]
        """Each group's (5,) result: NEGATIVES, LOWEST, LOWEST_ERROR, INVERSE_NORM, SHIFT."""
        self.negatives = np.array([int(r[NEGATIVES]) for r in self.results], np.int64)
        """Negative pivots of each group's Hessian (G,)."""
        for k, result in enumerate(self.results):
            self.stability.record(k, result, self.residuals[k])

    def _certify(self, k: int):
        layout = self.layout
        if not layout.banded:
            return certify_patch(self.model, self.positions, self.anchors, self.limit)
        ties, fixed, yarn = layout.chains[k]
        return certify_yarn(self.positions[layout.nodes[k]], yarn, self.anchors[ties, 0], fixed,
                            self.residuals[k])

    def escaped(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions (n, dim) [m] with every group on a saddle moved along its escape (the
        others as they are), which groups moved (G,) bool)."""
        layout = self.layout
        out = self.positions.copy()
        moved = np.zeros(len(layout.groups), np.bool_)
        for k, check in enumerate(self.checks):
            if self.negatives[k] == 0:
                continue
            if layout.banded:
                ties, _, yarn = layout.chains[k]
                nodes = layout.nodes[k]
                escaped = escape_yarn(self.positions[nodes], yarn,
                                      self.loads[int(layout.groups[k][0])],
                                      self.anchors[ties, 0], *check)
                if escaped is not None:
                    out[nodes], moved[k] = escaped, True
            else:
                escaped = escape_patch(self.model, self.positions, self.loads, self.anchors,
                                       self.limit, check)
                if escaped is not None:
                    out[:], moved[k] = escaped, True
        return out, moved

    def scales(self) -> np.ndarray:
        """Each group's displacement scale [m] (`StepStability.scale`: the largest displacement
        of its nodes, at least SCALE_FLOOR times its longest chain)."""
        layout, rest = self.layout, self.layout.structure.rest_position
        return np.array([StepStability.scale(self.positions[nodes], rest[nodes], length)
                         for nodes, length in zip(layout.nodes, layout.lengths)])

    def fields(self) -> dict:
        """The record's certificate entries, (G,) each: `StepStability.fields` and
        negative_eigenvalues."""
        return {**self.stability.fields(), "negative_eigenvalues": self.negatives}

    def check(self, tolerances, accuracy: float, at_floor, precision: str, key: str) -> None:
        """`check_accuracy` for every group (SolverError for the first whose bound exceeds
        `accuracy` times its scale); the message names the group (`RunModel.group_name`) and,
        on the sparse route, the yarn and node where the bound is largest."""
        scales = self.scales()
        for k, check in enumerate(self.checks):
            if self.stability.error_estimate[k] <= accuracy * scales[k]:
                continue
            where = self.model.group_name(k)
            if not self.layout.banded and check.worst >= 0:
                where = f"{where} ({patch_location(self.model, check.worst)}: where the bound " \
                        "is largest)"
            check_accuracy(where, self.stability.error_estimate[k], scales[k],
                           self.residuals[k], float(tolerances[k]), accuracy,
                           bool(at_floor[k]), precision, key, self.stability.shift[k])


def certify_groups(model, positions, anchors, limit, loads, residuals,
                   layout: GroupLayout | None = None) -> GroupCertificates:
    """The certificate of a converged step of any model (docs/model.md section 6,
    `GroupCertificates`): flat positions (n, dim) [m], the step's anchors (T, 2) [m] in the
    structure's convention, F_T (T,) [N] at the positions (used by the sparse route; the banded
    one takes them from the positions), the end loads per chain (Y,) [N] (the escape's load
    term) and each group's residual (G,) [N]; `layout` the model's `GroupLayout` (made here if
    not given: a solver keeps one per model)."""
    layout = GroupLayout(model) if layout is None else layout
    return GroupCertificates(layout, positions, anchors, limit, loads, residuals)
