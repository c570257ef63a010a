"""The laws of a tie in a kernel: the series contact law, Gralen's friction limit and the
isotropic Huber stick-slip term (docs/model.md sections 3, 4, 10).

The one Warp form of each law, for every structure (`structure_forces`) and every integrator:

- contact: for a closure g > 0 the force R >= 0 solves
  g(R) = R / k_s - C_a expm1(-a_a R) - C_b expm1(-a_b R) (increasing and concave), by Newton
  from the lower bound k_s (g - C_a - C_b), stopping when a step no longer increases R (as
  `dynfab.model.terms.contact.force_from_closure`); R = 0 where open. expm1 by its Taylor series
  below |x| = 1/2 (u - 1 above), accurate to a few ulps near 0 (as np.expm1 and Kahan's
  (u - 1) x / log u, without a logarithm). The tangent
  dR/dg = 1 / (1/k_s + sum_m C_m a_m exp(-a_m R)) <= k_s (0 where open); the energy
  R^2 / (2 k_s) + sum_m (C_m / a_m)(1 - exp(-x)(1 + x)), x = a_m R, below x = 0.5 by the
  series sum_{n>=2} (-1)^n (n - 1) x^n / n! against cancellation (docs/model.md (3.5)-(3.7)).
- Gralen (docs/model.md (4.1)): F_T = alpha R + beta ell r_f (1 - exp(-R / R_0)) for R > 0,
  the onset factor as -expm1(-R / R_0); R_0 = 0 the literal jump; 0 where open.
- Huber (docs/model.md (4.4), (10.8)): on the slip s (2 components; a ground tie's second is
  0), the force -dH/ds = -k_t s sticking (k_t |s| <= F_T), -F_T s / |s| sliding; H and its
  Hessian (k_t I sticking; (F_T / |s|^3) [[s_y^2, -s_x s_y], [-s_x s_y, s_x^2]] sliding, or
  with `secant` the secant (F_T / |s|) I); the radial return of the anchor.

`law` arguments are the (T, 5) and (T, 4) arrays of every tie's rows, with the tie's index.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels.precision import epsilon, vector
from dynfab.model.terms.contact import MAX_NEWTON

NEWTON_STOP = 4e-16 / 2.220446049250313e-16
"""The contact Newton stops when a step is below this many epsilons of R (4e-16 R in
float64, as `dynfab.model.terms.contact`)."""
SERIES_TERMS = 40
"""Terms of the Kawabata energy's series at most (x < 0.5: 1e-18 relative long before)."""


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The tie-law `wp.func`s for one scalar type."""
    vec = vector(scalar)
    vec3 = wp.types.vector(3, scalar)
    newton_stop = NEWTON_STOP * epsilon(scalar)

    @wp.func(inline=True)
    def expm1(x: scalar, u: scalar) -> scalar:
        """exp(x) - 1 [-] from u = exp(x), to a few ulps: for |x| < 1/2 its Taylor series to
        x^15 / 15! by Horner's rule (the remainder below 1e-16 of the value there), else u - 1
        (whose rounding is then at most 2.6 eps of the value)."""
        result = u - scalar(1.0)
        if wp.abs(x) < scalar(0.5):  # x (1 + x/2 (1 + x/3 (... (1 + x/15))))
            term = scalar(1.0) + x * scalar(0.06666666666666667)  # 1/15
            term = scalar(1.0) + x * term * scalar(0.07142857142857142)  # 1/14
            term = scalar(1.0) + x * term * scalar(0.07692307692307693)  # 1/13
            term = scalar(1.0) + x * term * scalar(0.08333333333333333)  # 1/12
            term = scalar(1.0) + x * term * scalar(0.09090909090909091)  # 1/11
            term = scalar(1.0) + x * term * scalar(0.1)  # 1/10
            term = scalar(1.0) + x * term * scalar(0.1111111111111111)  # 1/9
            term = scalar(1.0) + x * term * scalar(0.125)  # 1/8
            term = scalar(1.0) + x * term * scalar(0.14285714285714285)  # 1/7
            term = scalar(1.0) + x * term * scalar(0.16666666666666666)  # 1/6
            term = scalar(1.0) + x * term * scalar(0.2)  # 1/5
            term = scalar(1.0) + x * term * scalar(0.25)  # 1/4
            term = scalar(1.0) + x * term * scalar(0.3333333333333333)  # 1/3
            term = scalar(1.0) + x * term * scalar(0.5)  # 1/2
            result = x * term
        return result

    @wp.func(inline=True)
    def series_law(R: scalar, law: wp.array2d(dtype=scalar), t: int) -> vec:
        """(g(R) [m], dR/dg [N/m]) at force R, sharing the exponentials."""
        decay_a = wp.exp(-law[t, 2] * R)
        decay_b = wp.exp(-law[t, 4] * R)
        g = R / law[t, 0] - law[t, 1] * expm1(-law[t, 2] * R, decay_a) \
            - law[t, 3] * expm1(-law[t, 4] * R, decay_b)
        tangent = scalar(1.0) / (scalar(1.0) / law[t, 0] + law[t, 1] * law[t, 2] * decay_a
                                 + law[t, 3] * law[t, 4] * decay_b)
        return vec(g, tangent)

    @wp.func(inline=True)
    def contact(g: scalar, law: wp.array2d(dtype=scalar), t: int) -> vec:
        """(R(g) [N], dR/dg [N/m] at R); (0, 0) where open (g <= 0)."""
        R = scalar(0.0)
        tangent = scalar(0.0)
        if g > scalar(0.0):
            R = wp.max(scalar(0.0), law[t, 0] * (g - law[t, 1] - law[t, 3]))
            for _ in range(MAX_NEWTON):
                at_R = series_law(R, law, t)
                tangent = at_R[1]
                step = (g - at_R[0]) * tangent
                if not step > scalar(newton_stop) * R:
                    break
                R += step
        return vec(R, tangent)

    @wp.func(inline=True)
    def kawabata_energy(C: scalar, a: scalar, R: scalar) -> scalar:
        """(C / a)(1 - exp(-x)(1 + x)), x = a R [J]; the series below x = 0.5."""
        x = a * R
        result = scalar(0.0)
        if x >= scalar(0.5):
            result = (C / a) * (scalar(1.0) - wp.exp(-x) * (scalar(1.0) + x))
        else:
            term = x * x / scalar(2.0)
            floor = scalar(1.0e-18) * term + scalar(1.0e-300)
            total = scalar(0.0)
            n = int(2)
            while n < SERIES_TERMS and wp.abs(term) * scalar(n - 1) > floor:
                total += scalar(n - 1) * term
                n += 1
                term *= -x / scalar(n)
            result = (C / a) * total
        return result

    @wp.func(inline=True)
    def contact_energy(R: scalar, law: wp.array2d(dtype=scalar), t: int) -> scalar:
        """The series springs' energy at the common force R [J]."""
        return (R * R / (scalar(2.0) * law[t, 0]) + kawabata_energy(law[t, 1], law[t, 2], R)
                + kawabata_energy(law[t, 3], law[t, 4], R))

    @wp.func(inline=True)
    def limit(R: scalar, law: wp.array2d(dtype=scalar), t: int) -> scalar:
        """F_T [N] at contact force R (Gralen with its onset; 0 where open)."""
        value = scalar(0.0)
        if R > scalar(0.0):
            onset_factor = scalar(1.0)
            onset = law[t, 2]
            if onset > scalar(0.0):
                x = -R / onset
                onset_factor = -expm1(x, wp.exp(x))
            value = law[t, 0] * R + law[t, 1] * onset_factor
        return value

    huber = huber_term(vec)

    @wp.func(inline=True)
    def huber_hessian(s: vec, bound: scalar, stick: scalar, secant: int) -> vec3:
        """(h_xx, h_xy, h_yy) [N/m] of d2H/ds2, F_T frozen; with `secant` != 0 the secant
        (F_T / |s|) I while sliding; zeros where F_T = 0 or k_t = 0."""
        h = vec3(scalar(0.0), scalar(0.0), scalar(0.0))
        if stick > scalar(0.0) and bound > scalar(0.0):
            size = wp.length(s)
            if stick * size <= bound:
                h = vec3(stick, scalar(0.0), stick)
            elif secant != 0:
                h = vec3(bound / size, scalar(0.0), bound / size)
            else:
                scale = bound / (size * size * size)
                h = vec3(scale * s[1] * s[1], -scale * s[0] * s[1], scale * s[0] * s[0])
        return h

    @wp.func(inline=True)
    def return_anchor(s: vec, bound: scalar, stick: scalar) -> vec:
        """The anchor's move [m]: (1 - F_T / (k_t |s|)) s where k_t |s| > F_T, else 0."""
        move = vec(scalar(0.0), scalar(0.0))
        size = wp.length(s)
        if stick * size > bound:
            move = (scalar(1.0) - bound / (stick * size)) * s
        return move

    return SimpleNamespace(expm1=expm1, series_law=series_law, contact=contact,
                           contact_energy=contact_energy, limit=limit,
                           huber_force=huber.force, huber_energy=huber.energy,
                           huber_hessian=huber_hessian,
                           return_anchor=return_anchor)


@functools.cache
def huber_term(vec) -> SimpleNamespace:
    """The Huber stick-slip term (docs/model.md (4.4), (10.8)) on a slip of `vec`'s length: the
    planar ties' two components, a spatial crossing's three (`spatial_terms`):

    - force(s, F_T, k_t) = -dH/ds [N]: -k_t s sticking (k_t |s| <= F_T), -F_T s / |s| sliding;
    - energy(s, F_T, k_t) = H [J]: 1/2 k_t |s|^2 sticking, F_T |s| - F_T^2 / (2 k_t) sliding,
      0 where k_t = 0 (an open tie, F_T = 0, gives 0 either way).
    """
    scalar = vec._wp_scalar_type_

    @wp.func(inline=True)
    def force(s: vec, bound: scalar, stick: scalar) -> vec:
        trial = -stick * s
        size = wp.length(trial)
        if size > bound:
            trial = trial * (bound / size)
        return trial

    @wp.func(inline=True)
    def energy(s: vec, bound: scalar, stick: scalar) -> scalar:
        value = scalar(0.0)
        if stick > scalar(0.0):
            size = wp.length(s)
            if stick * size <= bound:
                value = scalar(0.5) * stick * size * size
            else:
                value = bound * size - bound * bound / (scalar(2.0) * stick)
        return value

    return SimpleNamespace(force=force, energy=energy)
