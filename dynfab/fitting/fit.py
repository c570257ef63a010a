"""Identify scene parameters from a measured traction curve (`dynfab fit`, docs/model.md "Fitting").

`fit(scene, data, keys)` replaces the scene's load path by the curve's load
column(s) (a fabric's warp and weft columns; refined by `substeps`), and
minimises the weighted residuals of the measured columns with
`scipy.optimize.least_squares` (trust region reflective, bounds). The
Jacobian of the one-yarn model is the exact sensitivities of
`dynfab.fitting.sensitivity`; the fabric has none and uses forward differences of
whole path solves (`FD_STEP`; fit.json says "jacobian": "finite-difference"
and a warning says why). What each model offers the fit is
`dynfab.fitting.models`. Positive keys are fitted in log space, the others as
they are.

Statistics at the solution (`statistics`), with J the Jacobian of the
weighted residuals in the fitted coordinates theta (log p or p):

- covariance: the Gauss-Newton (J^T J)^-1, scaled by the residual variance
  s^2 = |r|^2 / dof (dof = residuals - free parameters) when the noise is
  estimated, NOT rescaled when the curve gives a sigma column (the weights
  are then the known noise); 95 % intervals theta +- q se, q the Student t
  quantile with dof degrees of freedom (estimated noise) or the normal one
  (given sigma). For a log-fitted key the interval is exp of the log-space
  interval, asymmetric in the value; its `standard_error` is the first-order
  p x se(log p).
- identifiability: the singular values of J with unit-norm columns; a
  direction whose singular value is below RANK_TOLERANCE x the largest is
  numerically rank deficient (1e-6 for the exact Jacobian, exact to about
  1e-8; 1e-4 for forward differences, exact to about 1e-5), and a
  log-fitted key whose log-space standard error exceeds LOG_SE_LIMIT is not
  determined by the curve either (its 95 % interval would span more than a
  factor e^(2 q LOG_SE_LIMIT), 7 to 10). Either way the keys of the
  weakest combination get no interval and a warning names the combination.
- a key at an active bound gets no interval and a warning.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from dynfab import scene as scene_module
from dynfab.errors import UserError, SolverError
from dynfab.model.builders import scene_kind
from dynfab.results.measured_curve import MODELS, CurveData, read_curve
from dynfab.fitting.models import fit_model, start_value
from dynfab.scene import scene_to_toml, validate_scene, with_key

# scipy.optimize, scipy.stats and the solver (numba) are imported where used: `import dynfab`
# stays light.

RANK_TOLERANCE = {"exact": 1e-6, "finite-difference": 1e-4}
"""Singular value ratio of the column-scaled Jacobian below which a direction is rank deficient,
by how the Jacobian was computed: exact to about 1e-8, or by forward differences, whose error
is up to a few 1e-5 of a column (FD_STEP)."""
FD_STEP = 1e-6
"""Forward-difference step of a whole path solve in the fitted coordinates: a relative change
1e-6 of a log-fitted key, 1e-6 of its scale for the others. It balances the truncation, 1e-6
of the curve's relative curvature in the key, against the solver's noise (residual 1e-11 N)
over the step; tests/test_fit_fabric.py checks the result against central differences."""
FD_WARNING = ("finite-difference Jacobian (forward differences of whole path solves, step "
              "{step:g} in the fitted coordinates, {solves} extra solves per iteration): exact "
              "path sensitivities exist for the one-yarn model only")
"""The warning of a fit whose Jacobian is a finite difference (fit.json, the printed table)."""
LOG_SE_LIMIT = 0.5
"""Largest log-space standard error of an identified log-fitted key (a factor ~ 7 at 95 %)."""
MIN_PATH_STEPS = 16
"""The default substeps give the load path at least this many steps (a guard for Newton; the
friction curve itself does not depend on the sampling, tests/test_fit.py shows it)."""


@dataclass(frozen=True)
class Parameter:
    """One fitted key: start value, coordinates and bounds (in the value)."""

    key: str
    start: float
    log: bool
    lower: float
    upper: float

    def to_theta(self, value):
        return np.log(value) if self.log else value

    def from_theta(self, theta):
        return float(np.exp(theta)) if self.log else float(theta)


@dataclass
class FitResult:
    """What `fit` found: the report of fit.json, the fitted scene and curves."""

    parameters: dict
    correlation: list
    residual_rms: dict
    dof: int
    iterations: int
    identifiable: bool
    converged: bool
    warnings: list
    noise: dict
    scene: object
    """The fitted scene, its load path the fitted one (runs as it is)."""
    data: CurveData
    fitted: dict
    """name -> the model's curve at the data points (fitted parameters)."""
    cost_history: list = field(default_factory=list)
    jacobian: str = "exact"
    """"exact" or "finite-difference": the Jacobian the optimiser used."""
    cost: float = math.nan
    """Half the sum of squared weighted residuals at the solution (what the optimiser
    minimises)."""
    starts: dict | None = None
    """A fit from several starts (`dynfab.fitting.starts`): their count, how many reached this
    fit's cost, how many failed, each start and where it ended; None for one start."""

    def report(self) -> dict:
        """The JSON report (fit.json)."""
        return {"parameters": self.parameters, "jacobian": self.jacobian,
                "correlation": self.correlation,
                "residual_rms": self.residual_rms, "dof": self.dof,
                "iterations": self.iterations, "identifiable": self.identifiable,
                "converged": self.converged, "noise": self.noise, "warnings": self.warnings,
                "cost": self.cost, **({"starts": self.starts} if self.starts else {})}

    def table(self) -> str:
        """The parameters as a printed table."""
        lines = [f"{'parameter':<22}{'value':>13}{'std error':>12}  95 % interval"]
        for key, entry in self.parameters.items():
            se = entry["standard_error"]
            if entry["ci95"] is None:
                interval = "none (" + entry["status"] + ")"
            else:
                interval = f"[{entry['ci95'][0]:.6g}, {entry['ci95'][1]:.6g}]"
            se_text = f"{se:12.4g}" if se is not None else f"{'-':>12}"
            lines.append(f"{key:<22}{entry['value']:13.6g}{se_text}  {interval}")
        rms = ", ".join(f"{k} {v:.4g}" for k, v in self.residual_rms.items())
        lines.append(f"residual rms: {rms}; dof {self.dof}; iterations {self.iterations}; "
                     f"identifiable: {'yes' if self.identifiable else 'NO'}"
                     + ("" if self.converged else "; NOT CONVERGED"))
        if self.starts:
            lines.append(f"starts: {self.starts['count']}; {self.starts['reached_best']} reached "
                         f"the best cost (within {self.starts['tolerance']:g} of it), "
                         f"{self.starts['failed']} failed")
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


# --------------------------------------------------------------------------
# Setting up: keys, bounds, the load path.


def fittable_keys(scene) -> tuple[str, ...]:
    """The keys a fit of the scene may vary (`dynfab.fitting.models`): for the one-yarn model the
    numeric, sweepable keys whose table the scene has (docs/model.md section 1); for a fabric
    the real keys of [warp], [weft], [friction], [contact], [gravity] that it has."""
    return fit_model(scene).fittable_keys(scene)


def parse_keys(keys) -> list[str]:
    """A list of keys from "a,b" or ["a", "b"]."""
    if isinstance(keys, str):
        keys = keys.split(",")
    keys = [k.strip() for k in keys if k.strip()]
    if not keys:
        raise UserError("--fit: give at least one scene key, e.g. warp.kawabata_K")
    return keys


def parse_bounds(texts) -> dict:
    """{key: (lower, upper)} from "key=lo:hi" strings (either side may be empty)."""
    bounds = {}
    for text in texts or ():
        key, eq, rest = text.partition("=")
        lo, colon, hi = rest.partition(":")
        try:
            if not (eq and colon):
                raise ValueError
            bounds[key.strip()] = (float(lo) if lo.strip() else -math.inf,
                                   float(hi) if hi.strip() else math.inf)
        except ValueError:
            raise UserError(f"--bounds {text}: write KEY=LOWER:UPPER, e.g. "
                             "warp.kawabata_K=0.01:5") from None
    return bounds


def make_parameters(scene, keys, bounds=None, start=None) -> list[Parameter]:
    """Check the keys and bounds against the scene; the fitted coordinates of each key."""
    if scene.sweep or scene.geometry.yarns != 1:
        raise UserError("a fit takes one simulated yarn: remove the [sweep] and set "
                         "geometry.yarns = 1")
    allowed = fittable_keys(scene)
    model = scene_kind(scene)
    bounds, start = dict(bounds or {}), dict(start or {})
    parameters = []
    for key in keys:
        if key not in allowed:
            raise UserError(f"--fit {key}: cannot be fitted; a fitted key of {MODELS[model][0]} "
                             f"is one of: {', '.join(allowed)}")
        if key in (p.key for p in parameters):
            raise UserError(f"--fit {key}: given twice")
        if key.endswith(".linear_density") and scene.gravity is None:
            raise UserError(f"--fit {key}: a static curve does not depend on the mass without "
                             "[gravity]; it cannot be fitted from this scene")
        table, name = key.split(".")
        rule = scene_module._SCHEMA[table][1][name].rule
        value = start[key] if key in start else start_value(scene, key)
        log = rule == "positive"
        lower, upper = bounds.pop(key, (-math.inf, math.inf))
        if rule in ("positive", "nonnegative"):
            lower = max(lower, 0.0)
        if not lower <= value <= upper or not lower < upper:
            raise UserError(f"--bounds {key}={lower}:{upper}: the start value {value:g} must lie "
                             "within them (lower < upper)")
        parameters.append(Parameter(key, float(value), log, lower, upper))
    if bounds:
        raise UserError(f"--bounds {next(iter(bounds))}: not a fitted key (--fit)")
    return parameters


def default_substeps(points: int) -> int:
    """Steps per data interval: enough for a path of MIN_PATH_STEPS steps."""
    return max(1, math.ceil(MIN_PATH_STEPS / points))


def refined_path(load: np.ndarray, substeps: int) -> tuple[np.ndarray, np.ndarray]:
    """The load path (each data interval, from 0, cut in `substeps` equal steps, every column
    in proportion) and the indices of the data points in it. `load` is (points,) or, a
    fabric's (warp value, weft value), (points, 2); the path is the same shape."""
    load = np.asarray(load, float)
    rows = load.reshape(load.shape[0], -1)
    previous, path, index = np.zeros(rows.shape[1]), [], []
    for value in rows:
        cuts = substeps if (value != previous).any() else 1  # a first point at 0: one step
        fractions = np.arange(1, cuts + 1)[:, None] / cuts
        path.extend(previous + (value - previous) * fractions)
        path[-1] = value  # exactly the data's value
        index.append(len(path) - 1)
        previous = value
    path = np.asarray(path)
    return (path[:, 0] if load.ndim == 1 else path), np.asarray(index)


def with_path(scene, path: np.ndarray, weft: bool = True):
    """The scene with its load path replaced (control and factors unchanged): `path` (steps,)
    the values, or a fabric's (steps, 2) values and weft_values (`weft` False: no
    weft_values, the wefts' load 0, the scene's default)."""
    path = np.asarray(path, float)
    values = tuple(float(v) for v in (path if path.ndim == 1 else path[:, 0]))
    weft_values = (tuple(float(v) for v in path[:, 1]) if path.ndim == 2 and weft else None)
    return validate_scene(replace(scene, load=replace(scene.load, values=values,
                                                      weft_values=weft_values)))


# --------------------------------------------------------------------------
# The fit.


class _Problem:
    """Residuals and their Jacobian in the fitted coordinates: the exact sensitivities of the
    one-yarn model, forward differences of whole path solves for the fabric
    (`dynfab.fitting.models`)."""

    def __init__(self, scene, data: CurveData, parameters, data_index, progress):
        self.scene, self.data, self.parameters = scene, data, parameters
        self.data_index, self.progress = data_index, progress
        self.model = fit_model(scene)
        self.names = list(data.measured)
        self.sigma_given = bool(data.sigma)
        self.weights = [data.sigma[n] if self.sigma_given else
                        np.full(data.points, max(np.abs(data.measured[n]).max(), 1e-300))
                        for n in self.names]
        self.cache = {}
        self.iteration, self.last_theta, self.costs = 0, None, []

    @property
    def jacobian_kind(self) -> str:
        """"exact" or "finite-difference": what `jacobian` computes."""
        return "exact" if self.model.exact else "finite-difference"

    def values(self, theta):
        return [p.from_theta(t) for p, t in zip(self.parameters, theta)]

    def scene_at(self, theta):
        scene = self.scene
        for p, value in zip(self.parameters, self.values(theta)):
            scene = with_key(scene, p.key, value)
        return scene

    def evaluate(self, theta):
        """(solution, weighted residuals) at theta, solved afresh; a solver failure raises."""
        solution = self.model.solve(self.scene_at(theta), self.names)
        residual = np.concatenate([
            (solution.observables[n][self.data_index] - self.data.measured[n]) / w
            for n, w in zip(self.names, self.weights)])
        return solution, residual

    def solve(self, theta):
        """`evaluate`, cached at the last theta asked."""
        key = tuple(np.asarray(theta, float))
        if key not in self.cache:
            self.cache = {key: self.evaluate(theta)}
        return self.cache[key]

    def residuals(self, theta):
        try:
            return self.solve(theta)[1]
        except (SolverError, UserError):  # a trial point the model refuses: the step is rejected
            return np.full(self.data.residual_count, np.nan)

    def jacobian(self, theta, report=True):
        """d(weighted residuals)/d(theta); `report`: one progress line (an optimiser iteration)."""
        solution, residual = self.solve(theta)
        jac = (self._exact(theta, solution) if self.model.exact
               else self._forward_difference(theta, residual))
        if report:
            self._report(theta, residual)
        return jac

    def _exact(self, theta, solution):
        """The sensitivities of `dynfab.fitting.sensitivity`, times dp/dtheta, over the weights."""
        from dynfab.fitting.sensitivity import path_sensitivities

        values = self.values(theta)
        keys = [p.key for p in self.parameters]
        sens = path_sensitivities(solution, keys, values, self.names)
        chain = np.array([v if p.log else 1.0 for p, v in zip(self.parameters, values)])
        return np.concatenate([sens[n][self.data_index] * chain[None, :] / w[:, None]
                               for n, w in zip(self.names, self.weights)])

    def _forward_difference(self, theta, residual):
        """(r(theta + h_k e_k) - r(theta)) / h_k, one whole path solve per parameter, h_k =
        FD_STEP in log p, FD_STEP x the key's scale in p (`sensitivity.parameter_scale`),
        taken backward where the forward step would leave the upper bound. A solve that fails
        at the step is the user's to know of: SolverError."""
        from dynfab.fitting.sensitivity import parameter_scale

        jac = np.empty((residual.size, theta.size))
        for k, p in enumerate(self.parameters):
            value = p.from_theta(theta[k])
            h = FD_STEP * (1.0 if p.log else parameter_scale(self.scene, p.key, value))
            if p.to_theta(p.upper) < theta[k] + h:
                h = -h
            shifted = np.array(theta, float)
            shifted[k] += h
            h = shifted[k] - theta[k]  # the step as represented
            jac[:, k] = (self.evaluate(shifted)[1] - residual) / h
        return jac

    def _report(self, theta, residual):
        cost = 0.5 * float(residual @ residual)
        self.costs.append(cost)
        step = 0.0 if self.last_theta is None else float(np.abs(theta - self.last_theta).max())
        self.last_theta = np.array(theta, float)
        if self.progress is not None:
            shown = ", ".join(f"{p.key} {v:.6g}" for p, v in zip(self.parameters,
                                                                 self.values(theta)))
            self.progress(f"fit iteration {self.iteration}: cost {cost:.6g}, step {step:.3g}, "
                          f"{shown}")
        self.iteration += 1


def fit(scene, data, keys, *, bounds=None, substeps: int | None = None, start=None,
        progress: Callable[[str], None] | None = None, out=None, max_iterations: int = 50,
        jacobian: str | None = None) -> FitResult:
    """Fit `keys` of `scene` (a Scene or a scene file) to the measured curve `data` (a CSV path
    or a CurveData).

    `bounds`: {key: (lower, upper)} in the value; `start`: {key: value} instead of the
    scene's; `substeps`: load steps per data interval (default `default_substeps`);
    `progress`: receives a line per optimiser iteration; `out`: a folder for fit.json,
    fitted.toml and the figures; `jacobian`: "exact" (the sensitivities, the one-yarn
    model's default and only there) or "finite-difference" (the fabric's default and only
    Jacobian: `_Problem._forward_difference`; for the one-yarn model a comparison, scipy's
    "2-point" differences of whole runs for the optimiser, the statistics still exact).
    From several starting points on a Dask cluster: `dynfab.fitting.starts.fit_from_starts`.
    """
    from scipy.optimize import least_squares

    if isinstance(scene, (str, Path)):
        from dynfab.scene import load_scene
        scene = load_scene(scene)
    keys = parse_keys(keys)
    jacobian = _jacobian_for(scene, jacobian)
    model = scene_kind(scene)
    if not isinstance(data, CurveData):
        data = read_curve(data, scene.load.control, model)
    if data.model != model:
        raise UserError(f"{data.source}: a curve of {MODELS[data.model][0]} for a scene of "
                         f"{MODELS[model][0]}")
    if data.control != scene.load.control:
        raise UserError(f"{data.source}: a curve under {data.control} control for a scene under "
                         f"{scene.load.control} control")
    parameters = make_parameters(scene, keys, bounds, start)
    _check_counts(data, parameters)
    substeps = default_substeps(data.points) if substeps is None else int(substeps)
    if substeps < 1:
        raise UserError(f"--substeps {substeps}: must be at least 1")
    path, data_index = refined_path(data.path, substeps)
    problem = _Problem(with_path(scene, path, weft=data.weft_load is not None), data,
                       parameters, data_index, progress)
    theta0 = np.array([p.to_theta(p.start) for p in parameters])
    problem.solve(theta0)  # a start the solver cannot run is the user's to fix: raise here
    lower = np.array([p.to_theta(p.lower) if p.lower > 0 or not p.log else -np.inf
                      for p in parameters])
    upper = np.array([p.to_theta(p.upper) for p in parameters])
    result = least_squares(problem.residuals, theta0,
                           jac=problem.jacobian if jacobian == problem.jacobian_kind
                           else "2-point",
                           bounds=(lower, upper), method="trf", x_scale="jac",
                           max_nfev=max_iterations * (len(parameters) + 2))
    fitted = _finish(problem, result, parameters, jacobian)
    if out is not None:
        write_outputs(fitted, out)
    return fitted


def _jacobian_for(scene, jacobian: str | None) -> str:
    """The Jacobian a fit of the scene uses: `jacobian` as asked, or the model's own (exact
    for the one-yarn model, finite differences for the fabric, which has no exact one)."""
    own = "exact" if fit_model(scene).exact else "finite-difference"
    if jacobian is None:
        return own
    if jacobian not in ("exact", "finite-difference"):
        raise UserError(f"jacobian={jacobian!r}: 'exact' or 'finite-difference'")
    if jacobian == "exact" and own != "exact":
        raise UserError(f"jacobian='exact': exact path sensitivities exist for the one-yarn "
                         f"model only; a fit of {MODELS[scene_kind(scene)][0]} uses "
                         "'finite-difference'")
    return jacobian


def _check_counts(data: CurveData, parameters) -> None:
    m, p = data.residual_count, len(parameters)
    if not data.sigma and m <= p:
        raise UserError(f"{data.source}: {m} measured values for {p} parameters: with the noise "
                         "estimated from the residuals a fit needs more values than parameters")
    if m < p:
        raise UserError(f"{data.source}: {m} measured values for {p} parameters: too few")


def _finish(problem: _Problem, result, parameters, jacobian: str) -> FitResult:
    theta = result.x
    solution, residual = problem.solve(theta)
    jac = problem.jacobian(theta, report=False)
    active = np.asarray(result.active_mask) != 0
    values = problem.values(theta)
    report = statistics(jac, residual, theta, parameters, problem.sigma_given, active,
                        RANK_TOLERANCE[problem.jacobian_kind])
    warnings = report.pop("warnings")
    if problem.jacobian_kind == "finite-difference":
        warnings.insert(0, FD_WARNING.format(step=FD_STEP, solves=len(parameters)))
    if not result.success:
        warnings.insert(0, f"the optimiser did not converge: {result.message}")
    fitted_scene = problem.scene_at(theta)
    curves = {n: solution.observables[n][problem.data_index] for n in problem.names}
    rms = {n: float(np.sqrt(np.mean((curves[n] - problem.data.measured[n]) ** 2)))
           for n in problem.names}
    for key, value in zip([p.key for p in parameters], values):
        report["parameters"][key]["value"] = value
    scale = math.sqrt(report["noise"].pop("residual_variance_scale"))
    report["noise"]["sigma"] = {  # the noise level used [SI]: given (mean), or s x column scale
        n: float(np.mean(w) * (1.0 if problem.sigma_given else scale))
        for n, w in zip(problem.names, problem.weights)}
    return FitResult(parameters=report["parameters"], correlation=report["correlation"],
                     residual_rms=rms, dof=report["dof"], iterations=int(result.njev or 0),
                     identifiable=report["identifiable"], converged=bool(result.success),
                     warnings=warnings, noise=report["noise"], scene=fitted_scene,
                     data=problem.data, fitted=curves, cost_history=problem.costs,
                     jacobian=jacobian, cost=0.5 * float(residual @ residual))


# --------------------------------------------------------------------------
# Statistics.


def statistics(jac, residual, theta, parameters, sigma_given: bool, active,
               rank_tolerance: float = RANK_TOLERANCE["exact"]) -> dict:
    """Standard errors, 95 % intervals, correlation and identifiability (module docstring);
    `rank_tolerance`: RANK_TOLERANCE of how `jac` was computed."""
    from scipy import stats as scipy_stats

    m, n = jac.shape
    keys = [p.key for p in parameters]
    free = ~np.asarray(active, bool)
    dof = m - int(free.sum())
    variance = 1.0 if sigma_given else float(residual @ residual) / max(dof, 1)
    quantile = (scipy_stats.norm.ppf(0.975) if sigma_given
                else scipy_stats.t.ppf(0.975, max(dof, 1)))
    warnings = []
    cov = np.full((n, n), np.nan)
    undetermined = np.zeros(n, bool)
    idx = np.flatnonzero(free)
    for k in idx[np.linalg.norm(jac[:, idx], axis=0) == 0.0]:
        warnings.append(f"not identifiable: {keys[k]}; the curve does not depend on it")
        undetermined[k] = True
    idx = idx[~undetermined[idx]]
    if idx.size:
        sub = jac[:, idx]
        scale = np.linalg.norm(sub, axis=0)
        _, s, vt = np.linalg.svd(sub / scale, full_matrices=False)
        ratio = s / s[0] if s[0] > 0 else np.zeros_like(s)
        inv = np.where(ratio > 1e-14, 1.0 / np.where(s > 0, s, 1.0) ** 2, np.inf)
        with np.errstate(invalid="ignore"):
            cov_scaled = (vt.T * np.where(np.isfinite(inv), inv, 0.0)) @ vt
        cov_sub = variance * cov_scaled / np.outer(scale, scale)
        cov[np.ix_(idx, idx)] = cov_sub

        def combination(i):
            """The direction vt[i] as text, its largest component positive."""
            sign = 1.0 if vt[i][np.argmax(np.abs(vt[i]))] > 0 else -1.0
            text = ""
            for j in np.flatnonzero(np.abs(vt[i]) > 0.1):
                c = sign * vt[i][j]
                name = f"{'log ' if parameters[idx[j]].log else ''}{keys[idx[j]]}"
                text += (f"{'-' if c < 0 else ''}{abs(c):.3g} {name}" if not text
                         else f" {'-' if c < 0 else '+'} {abs(c):.3g} {name}")
            return text

        for i in np.flatnonzero(ratio < rank_tolerance):
            members = idx[np.abs(vt[i]) > 0.1]
            undetermined[members] = True
            warnings.append(
                f"not identifiable: {', '.join(keys[k] for k in members)}; the curve does not "
                f"determine the combination ({combination(i)}) of the column-scaled Jacobian "
                f"(singular value ratio {ratio[i]:.2g} < {rank_tolerance:g})")
        loose = {}  # weakest direction -> keys whose log-space error is too large
        for j, k in enumerate(idx):
            se_log = math.sqrt(cov[k, k]) if np.isfinite(cov[k, k]) else math.inf
            if undetermined[k] or not parameters[k].log or se_log <= LOG_SE_LIMIT:
                continue
            weakest = int(np.argmax(np.abs(vt[:, j]) / np.where(s > 0, s, 1e-300)))
            loose.setdefault(weakest, []).append((k, se_log))
        for weakest, members in loose.items():
            undetermined[[k for k, _ in members]] = True
            errors = ", ".join(f"{keys[k]} {se:.3g}" for k, se in members)
            warnings.append(
                f"not identifiable: {', '.join(keys[k] for k, _ in members)}; log-space standard "
                f"error above {LOG_SE_LIMIT:g} ({errors}; a 95 % interval wider than a factor "
                f"{math.exp(2 * quantile * LOG_SE_LIMIT):.3g}); the curve hardly determines the "
                f"combination ({combination(weakest)}) of the column-scaled Jacobian "
                f"(singular value ratio {ratio[weakest]:.2g})")
    report = {}
    for k, p in enumerate(parameters):
        se_theta = math.sqrt(cov[k, k]) if np.isfinite(cov[k, k]) else None
        entry = {"value": p.from_theta(theta[k]), "fitted_in": "log" if p.log else "linear",
                 "standard_error": None, "ci95": None, "identified": bool(not undetermined[k]),
                 "at_bound": bool(not free[k]), "status": "ok"}
        if not free[k]:
            entry["status"] = "at a bound"
            warnings.append(f"{p.key} = {entry['value']:.6g} is at its bound "
                            f"[{p.lower:g}, {p.upper:g}]: no interval")
        elif undetermined[k] or se_theta is None:
            entry["status"] = "not identified"
            entry["identified"] = False
        else:
            lo, hi = theta[k] - quantile * se_theta, theta[k] + quantile * se_theta
            entry["standard_error"] = (entry["value"] * se_theta) if p.log else se_theta
            entry["ci95"] = [p.from_theta(lo), p.from_theta(hi)]
            if p.log:
                entry["standard_error_log"] = se_theta
        report[p.key] = entry
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.sqrt(np.diag(cov))
        corr = cov / np.outer(d, d)
    correlation = [[None if not np.isfinite(v) else float(v) for v in row] for row in corr]
    noise = {"estimated": not sigma_given, "residual_variance_scale": variance,
             "interval_quantile": float(quantile),
             "quantile": "normal (sigma given)" if sigma_given else f"Student t, {dof} dof"}
    return {"parameters": report, "correlation": correlation, "dof": dof,
            "identifiable": bool(not undetermined.any()), "noise": noise, "warnings": warnings}


# --------------------------------------------------------------------------
# Output.


def write_outputs(result: FitResult, out) -> list[Path]:
    """fit.json, fitted.toml and the figures into the folder `out`; returns the paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    report_path, scene_path = out / "fit.json", out / "fitted.toml"
    report_path.write_text(json.dumps(result.report(), indent=2) + "\n")
    scene_path.write_text(scene_to_toml(result.scene))
    from dynfab.fitting.plots import plot_fit
    return [report_path, scene_path, *plot_fit(result, out)]
