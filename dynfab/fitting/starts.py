"""A fit from several starting points on a Dask cluster (`dynfab fit --starts K`).

A least-squares fit finds the minimum nearest its start; a curve with several (friction's
onset, a parameter that trades against another) is fitted from K starts, spread over the
cluster of `dynfab study` (`dynfab.studies.study`: an embedded LocalCluster, or `--scheduler`),
and the best fit (lowest cost) kept. Its report (fit.json "starts") says how many starts
reached that cost and how many failed.

The starts (`start_points`): the first is the fit's own (the scene's values, or `start`);
the other K - 1 are a seeded Latin hypercube (scipy.stats.qmc, seed 0) over a box in the
fitted coordinates (log p for positive keys, p otherwise): on each side the key's bound
where it is finite, else a factor `SPREAD` from the start for a positive key and
max(|start|, 1) from it for the others.

The data travel to the workers in memory (a `CurveData`), like a study's scenes: the
workers share no disk with the client, which writes fit.json and the figures.
"""

from __future__ import annotations

import math
import numpy as np

from dynfab.errors import SolverError, UserError

SPREAD = 10.0
"""A start's box without finite bounds: [start / SPREAD, start x SPREAD] for a positive
(log-fitted) key; [start - w, start + w] with w = max(|start|, 1) otherwise, cut to the bounds."""
REACHED = 1e-6
"""A start reached the best fit when its final cost is within this fraction of the best
cost: 100 x least_squares' ftol (1e-8), the relative change of the cost under which the
optimiser stops, so two runs that stop at one minimum agree to about that."""
SEED = 0


def start_points(parameters, count: int, seed: int = SEED) -> list[dict]:
    """`count` starts {key: value}: the parameters' own start, then a Latin hypercube in
    each parameter's box (module docstring)."""
    first = {p.key: p.start for p in parameters}
    if count <= 1:
        return [first]
    from scipy.stats import qmc

    boxes = [_box(p) for p in parameters]
    try:
        sampler = qmc.LatinHypercube(d=len(boxes), rng=np.random.default_rng(seed))
    except TypeError:  # scipy < 1.15 names it seed
        sampler = qmc.LatinHypercube(d=len(boxes), seed=np.random.default_rng(seed))
    points = [first]
    for row in sampler.random(count - 1):
        points.append({p.key: p.from_theta(low + u * (high - low))
                       for p, (low, high), u in zip(parameters, boxes, row)})
    return points


def _box(parameter) -> tuple[float, float]:
    """The start box of one parameter in its fitted coordinates (module docstring)."""
    p = parameter
    if p.log:
        low = math.log(p.lower) if p.lower > 0 else math.log(p.start / SPREAD)
        high = math.log(p.upper) if math.isfinite(p.upper) else math.log(p.start * SPREAD)
        low = max(low, math.log(p.lower)) if p.lower > 0 else low
        return low, high
    width = max(abs(p.start), 1.0)
    low = p.lower if math.isfinite(p.lower) else p.start - width
    high = p.upper if math.isfinite(p.upper) else p.start + width
    return max(low, p.lower), min(high, p.upper)


def fit_from_starts(scene, data, keys, *, starts: int, bounds=None, substeps=None, start=None,
                    progress=None, out=None, max_iterations: int = 50, jacobian=None,
                    scheduler: str | None = None, workers: int | None = None):
    """`dynfab.fitting.fit.fit` from `starts` starting points on a Dask cluster; the best fit, its
    `starts` report filled in (module docstring)."""
    from dynfab.fitting.fit import make_parameters, parse_keys
    from dynfab.model.builders import scene_kind
    from dynfab.results.measured_curve import CurveData, read_curve
    from dynfab.studies.study import _cluster

    if starts < 1:
        raise UserError(f"--starts {starts}: at least 1")
    keys = parse_keys(keys)
    if not isinstance(data, CurveData):
        data = read_curve(data, scene.load.control, scene_kind(scene))
    points = start_points(make_parameters(scene, keys, bounds, start), starts)
    options = dict(bounds=bounds, substeps=substeps, max_iterations=max_iterations,
                   jacobian=jacobian)
    outcomes = []
    with _cluster(scheduler, workers) as client:
        futures = [client.submit(_fit_one, scene, data, keys, point, options, pure=False)
                   for point in points]
        from distributed import as_completed

        for future in as_completed(futures):
            index = futures.index(future)
            outcome = future.result()
            outcomes.append((index, outcome))
            if progress is not None:
                progress(_start_line(index, len(points), points[index], outcome))
    outcomes.sort(key=lambda item: item[0])
    results = [o for _, o in outcomes if not isinstance(o, str)]
    if not results:
        raise SolverError(f"none of the {starts} starts could be fitted: {outcomes[0][1]}")
    best = min(results, key=lambda r: r.cost)
    reached = sum(r.cost <= best.cost * (1 + REACHED) for r in results)
    best.starts = {
        "count": starts, "reached_best": reached, "failed": starts - len(results),
        "tolerance": REACHED,
        "points": [{"start": points[i], **({"failed": o} if isinstance(o, str) else
                                          {"cost": o.cost, "values": {
                                              k: v["value"] for k, v in o.parameters.items()}})}
                   for i, o in outcomes]}
    if out is not None:
        from dynfab.fitting.fit import write_outputs

        write_outputs(best, out)
    return best


def _fit_one(scene, data, keys, start: dict, options: dict):
    """One start's fit, on a worker: its FitResult, or the failure's message."""
    from dynfab.fitting.fit import fit

    try:
        return fit(scene, data, keys, start=start, **options)
    except (SolverError, UserError) as error:
        return f"{type(error).__name__}: {error}"


def _start_line(index: int, total: int, start: dict, outcome) -> str:
    shown = ", ".join(f"{k} {v:.6g}" for k, v in start.items())
    if isinstance(outcome, str):
        return f"fit start {index + 1}/{total} from {shown}: failed: {outcome}"
    found = ", ".join(f"{k} {v['value']:.6g}" for k, v in outcome.parameters.items())
    return f"fit start {index + 1}/{total} from {shown}: cost {outcome.cost:.6g} at {found}"


