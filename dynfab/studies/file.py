"""Study files: a base scene, the keys to vary, the observables to gather (`dynfab study`).

A study file is TOML::

    title = "friction and core stiffness of the strip"
    scene = "fabric_strip.toml"      # the base scene, a path relative to this file
                                     # (or a [scene] table holding the scene's tables)
    solver = "static"                # or "dynamic" (default "static")
    design = "grid"                  # or "latin_hypercube" (default "grid")
    count = 16                       # latin_hypercube only: the number of cases
    seed = 0                         # latin_hypercube only: the sampling's seed (default 0)

    [vary]                           # grid: a list of values per key, every combination
    "friction.alpha" = [0.1, 0.2, 0.3]
    "contact.core_stiffness" = [1e3, 1e4]
                                     # latin_hypercube: [lower, upper] per key (real keys)

    [observe]                        # name = dataset, or a table {dataset, at}
    force = "end_force"              # every load step: (case, step, ...)
    final_strain = { dataset = "strain", at = "last" }     # the last step's value
    force_at = { dataset = "end_force", at = 0.5 }        # at the load 0.5 (N or m)

Any key of any scene table may be varied (docs/scene.md), in either model: a case's
scene is the base scene's tables with the case's values written in, parsed as a scene
file would be (so a key the base file leaves out takes the value, and defaults derived
from it follow, as in a file that wrote it). `at = LOAD` is the value where the load path
(load.values; a fabric's warps') passes LOAD, linear between the two steps around it,
the step's own value where LOAD is a step's.

Everything is validated here, before any case runs: every case's scene, every
observable's dataset name (`dynfab.results.file.UNITS`) and load. A mistake is a UserError
(one line, exit status 2) naming the key.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dynfab.model.builders import scene_kind
from dynfab.model.loading import RELAXATION_STEPS

from dynfab import scene as scene_module
from dynfab.errors import UserError
from dynfab.results.file import ENERGY_TERM, UNITS
from dynfab.scene import (SCENE_TABLES, Scene, parse_scene_text, parse_toml, read_text_file,
                          scene_from_tables)

DESIGNS = ("grid", "latin_hypercube")
"""How the cases are chosen: every combination of the listed values, or a Latin hypercube
sample of `count` points in the ranges (scipy.stats.qmc.LatinHypercube)."""
SOLVERS = ("static", "dynamic")
TOP_KEYS = ("title", "scene", "solver", "design", "count", "seed", "vary", "observe")
AT_LAST = "last"
"""`at` of an observable taken at the last load step."""
AT_PATH = "path"
"""`at` of an observable taken at every load step (the default)."""
MAX_CASES = 1_000_000
"""Most cases a study may have (each is a file)."""


@dataclass(frozen=True)
class Observable:
    """One gathered quantity: a `steps/` dataset, at every step, the last, or a load."""

    name: str
    dataset: str
    """Its name under steps/ ("end_force", "energy/stretch")."""
    at: str | float = AT_PATH
    """AT_PATH, AT_LAST or a load value [N or m, the scene's control]."""


@dataclass(frozen=True)
class Case:
    """One scene of the study: its number, its values of the varied keys, its scene."""

    index: int
    values: tuple
    """The varied keys' values, in `Study.parameters` order."""
    scene: Scene

    @property
    def text(self) -> str:
        """The case's scene as TOML: what travels to a worker and what its file stores."""
        return self.scene.text

    @property
    def path(self) -> np.ndarray:
        """The load value of each step of its run (`path_values`)."""
        return path_values(self.scene)

    @property
    def steps(self) -> int:
        """Load steps of its run."""
        return len(self.path)


def path_values(scene: Scene) -> np.ndarray:
    """The load value of each step a run of `scene` writes: load.values (a fabric's warps'),
    after a shear specimen's step 0 at d = 0 (the preload relaxed, docs/model.md section 11)."""
    steps = RELAXATION_STEPS[scene_kind(scene)]
    return np.concatenate([np.zeros(steps), np.asarray(scene.load.values, float)])


@dataclass(frozen=True)
class Study:
    """A validated study: its cases and what to gather."""

    title: str
    solver: str
    design: str
    parameters: tuple[str, ...]
    cases: tuple[Case, ...]
    observables: tuple[Observable, ...]
    base: Scene
    text: str
    """The study file's text as given."""
    count: int | None = None
    seed: int | None = None

    def fingerprint(self) -> str:
        """A digest of what the study computes (solver, cases' scenes, observables): equal for
        the same study, whatever the file's comments; `--resume` checks it."""
        record = {"solver": self.solver, "parameters": self.parameters,
                  "cases": [case.text for case in self.cases],
                  "observe": [[o.name, o.dataset, o.at] for o in self.observables]}
        return hashlib.sha256(json.dumps(record).encode()).hexdigest()

    def parameter_units(self) -> dict[str, str]:
        """Unit of each varied key ("N or m" resolved by the base scene's load.control)."""
        return {key: key_unit(self.base, key) for key in self.parameters}


def load_study(path) -> Study:
    """Read and validate the study file at `path` (UserError, one line, if it cannot)."""
    path = Path(path)
    return parse_study_text(read_text_file(path, "study file"), source=str(path),
                            folder=path.parent)


def parse_study_text(text: str, source: str = "<study>", folder=".") -> Study:
    """Parse and validate study TOML; `folder` resolves a relative `scene` path."""
    raw = parse_toml(text, source)
    for key in raw:
        if key not in TOP_KEYS:
            raise UserError(f"{source}: unknown key '{key}'; allowed: {', '.join(TOP_KEYS)}")
    base_text = _base_text(raw, Path(folder), source)
    base_raw = tomllib.loads(base_text)
    base = parse_scene_text(base_text, source=f"{source}: scene")
    if base.dynamic.mode == "transient":
        raise UserError('dynamic.mode = "transient": a study gathers load steps; a transient '
                        "scene writes frames (run it with dynfab run)")
    solver = _choice(raw, "solver", SOLVERS, "static")
    design = _choice(raw, "design", DESIGNS, "grid")
    vary = raw.get("vary")
    if not isinstance(vary, dict) or not vary:
        raise UserError("[vary]: give at least one scene key with its values, e.g. "
                        '"friction.alpha" = [0.1, 0.2]')
    swept = {key for key, _ in base.sweep}
    for key in vary:
        _check_vary_key(key)
        if key in swept:
            raise UserError(f'vary."{key}": the base scene\'s [sweep] varies it already; vary '
                            "it in one of them")
    count = seed = None
    if design == "grid":
        for key in ("count", "seed"):
            if key in raw:
                raise UserError(f'{key} = {raw[key]!r}: only design = "latin_hypercube" takes it')
        points = _grid(vary)
    else:
        count = _integer(raw, "count", None)
        seed = _integer(raw, "seed", 0, minimum=0)
        points = _latin_hypercube(vary, count, seed)
    parameters = tuple(vary)
    cases = tuple(Case(i, values, _case_scene(base_raw, parameters, values))
                  for i, values in enumerate(points))
    observables = _observables(raw.get("observe"), cases)
    title = raw.get("title", base.title)
    if not isinstance(title, str):
        raise UserError(f"title = {title!r}: must be a string")
    return Study(title=title, solver=solver, design=design, parameters=parameters, cases=cases,
                 observables=observables, base=base, text=text, count=count, seed=seed)


def key_unit(scene: Scene, dotted: str) -> str:
    """The unit of a scene key ("" if none), "N or m" resolved by the scene's control."""
    table, _, name = dotted.partition(".")
    spec = scene_module._SCHEMA[table][1].get(name) or scene_module._LOAD_PATH.get(name)
    unit = spec.unit if spec is not None else ""
    if unit == "N or m":
        return "N" if scene.load.control == "force" else "m"
    return unit


def observable_units(observable: Observable, control: str) -> str:
    """Units of an observable's values: its dataset's (`dynfab.results.file.UNITS`)."""
    name = observable.dataset
    if name.startswith("energy/"):
        return UNITS[f"steps/energy/{ENERGY_TERM}"]
    units = UNITS[f"steps/{name}"]
    return ("N" if control == "force" else "m") if units.startswith("<") else units


# --------------------------------------------------------------------------
# The base scene and the cases.


def _base_text(raw: dict, folder: Path, source: str) -> str:
    """The base scene's TOML: the file named by `scene`, or the [scene] table written out."""
    given = raw.get("scene")
    if isinstance(given, str):
        path = Path(given) if Path(given).is_absolute() else folder / given
        try:
            return path.read_bytes().decode("utf-8")
        except FileNotFoundError:
            raise UserError(f'scene = "{given}": scene file \'{path}\' not found') from None
        except (OSError, UnicodeDecodeError) as error:
            raise UserError(f'scene = "{given}": cannot read \'{path}\': {error}') from None
    if isinstance(given, dict):
        return scene_from_tables(given).text
    raise UserError(f"{source}: scene: give the base scene's file (scene = \"FILE.toml\") or "
                    "its tables ([scene.geometry], ...)")


def _choice(raw: dict, key: str, allowed: tuple[str, ...], default: str) -> str:
    value = raw.get(key, default)
    if value not in allowed:
        raise UserError(f"{key} = {json.dumps(value)}: must be one of "
                        + ", ".join(json.dumps(a) for a in allowed))
    return value


def _integer(raw: dict, key: str, default, minimum: int = 1) -> int:
    value = raw.get(key, default)
    if value is None:
        raise UserError(f'{key}: design = "latin_hypercube" needs the number of cases, '
                        f"e.g. {key} = 16")
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise UserError(f"{key} = {value!r}: must be an integer >= {minimum}")
    if key == "count" and value > MAX_CASES:
        raise UserError(f"count = {value}: at most {MAX_CASES} cases")
    return value


def _check_vary_key(key: str) -> None:
    """A varied key is "table.key" of a scene table; the scene parser checks the rest."""
    table, dot, name = key.partition(".")
    if not dot or table not in SCENE_TABLES or not name:
        raise UserError(f'vary."{key}": not a scene key; write "table.key" with a table of '
                        + ", ".join(SCENE_TABLES) + " (docs/scene.md)")


def _grid(vary: dict) -> list[tuple]:
    """Every combination of the listed values, the last key varying fastest."""
    lists = []
    for key, values in vary.items():
        if not isinstance(values, list) or not values:
            raise UserError(f'vary."{key}" = {values!r}: give a non-empty list of values '
                            '(design = "grid")')
        lists.append(values)
    total = math.prod(len(values) for values in lists)
    if total > MAX_CASES:
        raise UserError(f"[vary]: {total} combinations; at most {MAX_CASES} cases")
    return list(itertools.product(*lists))


def _latin_hypercube(vary: dict, count: int, seed: int) -> list[tuple]:
    """`count` points of a Latin hypercube in the ranges (scipy.stats.qmc), seeded."""
    ranges = []
    for key, bounds in vary.items():
        ok = (isinstance(bounds, list) and len(bounds) == 2
              and all(isinstance(b, (int, float)) and not isinstance(b, bool) for b in bounds)
              and all(math.isfinite(b) for b in bounds) and bounds[0] < bounds[1])
        if not ok:
            raise UserError(f'vary."{key}" = {bounds!r}: design = "latin_hypercube" takes a range '
                            "[lower, upper] of finite numbers, lower < upper")
        table, _, name = key.partition(".")
        spec = scene_module._SCHEMA[table][1].get(name)
        if spec is not None and spec.kind != "float":
            raise UserError(f'vary."{key}": design = "latin_hypercube" samples real values; this '
                            f"key takes {scene_module._KIND_TEXT.get(spec.kind, spec.kind)}s "
                            '(vary it with design = "grid")')
        ranges.append(bounds)
    from scipy.stats import qmc

    try:
        sampler = qmc.LatinHypercube(d=len(ranges), rng=np.random.default_rng(seed))
    except TypeError:  # scipy < 1.15 names it seed
        sampler = qmc.LatinHypercube(d=len(ranges), seed=np.random.default_rng(seed))
    unit = sampler.random(count)
    lower = np.array([r[0] for r in ranges], float)
    upper = np.array([r[1] for r in ranges], float)
    return [tuple(float(v) for v in lower + row * (upper - lower)) for row in unit]


def _case_scene(base_raw: dict, parameters: tuple[str, ...], values: tuple) -> Scene:
    """The base scene's tables with the case's values written in, parsed as a scene file."""
    tables = {name: (dict(value) if isinstance(value, dict) else value)
              for name, value in base_raw.items()}
    for key, value in zip(parameters, values):
        table, name = key.split(".", 1)
        tables.setdefault(table, {})
        tables[table][name] = value
        if table == "load" and name in ("max", "steps"):
            tables[table].pop("values", None)  # a path given by max/steps replaces the list
        if table == "load" and name == "values":
            tables[table].pop("max", None)
            tables[table].pop("steps", None)
    shown = ", ".join(f"{k} = {_show(v)}" for k, v in zip(parameters, values))
    try:
        return scene_from_tables(tables)
    except UserError as error:
        raise UserError(f"vary: the case {shown}: {error}") from None


def _show(value) -> str:
    return json.dumps(value) if isinstance(value, str) else f"{value:g}" if isinstance(
        value, float) else str(value)


# --------------------------------------------------------------------------
# Observables.


def _observables(raw, cases: tuple[Case, ...]) -> tuple[Observable, ...]:
    if not isinstance(raw, dict) or not raw:
        raise UserError('[observe]: name at least one dataset to gather, e.g. force = "end_force"')
    found = []
    for name, spec in raw.items():
        if not name.isidentifier():
            raise UserError(f"observe.{name}: a name of letters, digits and _ (not starting with "
                            "a digit)")
        if isinstance(spec, str):
            spec = {"dataset": spec}
        if not isinstance(spec, dict) or set(spec) - {"dataset", "at"} or "dataset" not in spec:
            raise UserError(f'observe.{name}: write a dataset name ("end_force") or a table '
                            '{ dataset = "end_force", at = "last" }')
        dataset = spec["dataset"]
        _check_dataset(name, dataset)
        at = spec.get("at", AT_PATH)
        if isinstance(at, bool) or not (at in (AT_PATH, AT_LAST) or isinstance(at, (int, float))):
            raise UserError(f"observe.{name}.at = {at!r}: \"path\" (every step), \"last\" or a "
                            "load value (N or m)")
        if isinstance(at, (int, float)):
            at = float(at)
            for case in cases:
                _check_load_reached(name, at, case)
        found.append(Observable(name, dataset, at))
    return tuple(found)


def _check_dataset(name: str, dataset) -> None:
    """A dataset a load step may write (`dynfab.results.file.UNITS`, steps/ but the XDMF rows)."""
    if isinstance(dataset, str) and dataset.startswith("energy/"):
        if dataset[len("energy/"):].replace("_", "").isalnum():
            return
    allowed = sorted(key[len("steps/"):] for key in UNITS
                     if key.startswith("steps/") and "<" not in key)
    if not isinstance(dataset, str) or dataset not in allowed:
        raise UserError(f"observe.{name}: dataset {dataset!r} is not a load step's dataset; "
                        "allowed: " + ", ".join(allowed) + ", energy/<term>")


def _check_load_reached(name: str, at: float, case: Case) -> None:
    if load_position(case.path, at) is None:
        values = case.scene.load.values
        raise UserError(f"observe.{name}.at = {at:g}: the load path of case {case.index} "
                        f"({values[0]:g} to {values[-1]:g}, {len(values)} steps) does not pass it")


def load_position(path: np.ndarray, at: float) -> tuple[int, float] | None:
    """(i, w): the load `at` is reached between steps i-1 and i of `path` at the fraction w
    from step i-1 (w = 1: step i itself; i = 0, w = 1: the first step); None if never."""
    if path.size and path[0] == at:
        return 0, 1.0
    for i in range(1, path.size):
        low, high = sorted((path[i - 1], path[i]))
        if low <= at <= high and path[i] != path[i - 1]:
            if at == path[i]:
                return i, 1.0
            return i, float((at - path[i - 1]) / (path[i] - path[i - 1]))
    return None


def case_fields(study: Study, case: Case) -> str:
    """"key = value, ..." of a case, for its lines and messages."""
    return ", ".join(f"{k} = {_show(v)}" for k, v in zip(study.parameters, case.values))


__all__ = ["Case", "Observable", "Study", "load_study", "parse_study_text", "key_unit",
           "observable_units", "load_position", "case_fields"]
