"""The solver contracts (`dynfab.solvers.contract`) and the load the model prescribes
(`dynfab.model.loading`).

Both load-step solvers are `Solver`s and give records of the same names when
driven through the contract alone; the transient mode is a `Transient`; a run
needs nothing of a solver but its contract; no solver module imports another.
The load prescription is checked against its closed form.
"""

import ast
import importlib
from pathlib import Path

import numpy as np
import pytest

from dynfab.solvers.dynamic import DynamicSolver, DynamicTransient
from dynfab.errors import UserError
from dynfab.model.loading import load_at_time, prescribe_load
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.results.file import MACHINE_TIMES, units_of
from dynfab.run import run
from dynfab.scene import load_scene, scene_keys, with_key
from dynfab.solvers.contract import FRAME_KEYS, STEP_KEYS, Solver, Transient
from dynfab.solvers.static import StaticSolver
from dynfab.solvers.by_name import make_solver
from dynfab.model.terms import registry
from dynfab.reports.fabric_data import paper_patch_scene
from independent import PAPER_FRICTION, PAPER_WARP, PAPER_WEFT, make_scene

run_module = importlib.import_module("dynfab.run")  # the module; dynfab.run is the function
ROOT = Path(__file__).resolve().parent.parent
RUNS = ROOT / "runs"


@pytest.fixture(scope="module")
def fig3():
    """Fig. 3's K sweep (three yarns batched), displacement control, one load step: the scene
    and dynamic options tests/test_dynamic_relaxation.py already builds kernels for."""
    return with_key(load_scene(RUNS / "paper_fig3.toml"), "load.values", [0.001])


@pytest.fixture(scope="module")
def relax():
    """relax.toml (transient, force control) shortened to two output intervals."""
    scene = with_key(load_scene(RUNS / "relax.toml"), "dynamic.duration", 4e-4)
    return with_key(scene, "dynamic.output_interval", 2e-4)


def drive(solver: Solver, state, loads):
    """Every (state, record) of `loads`, using nothing of `solver` but the Solver contract."""
    records = []
    for load in loads:
        state, record = solver.step(state, float(load))
        records.append(record)
    return state, records


def energy_names(record) -> set:
    return {name for name in record if name.startswith("energy/")}


def test_load_step_solvers_conform_to_the_solver_contract_only(fig3, relax):
    model = build_model(fig3)
    for solver in (StaticSolver(model), DynamicSolver(model)):
        assert isinstance(solver, Solver)
        assert not isinstance(solver, Transient)  # one contract per object: run picks by type
    transient = DynamicTransient(build_model(relax))
    assert isinstance(transient, Transient)
    assert not isinstance(transient, Solver)


def test_transient_contract_refuses_a_relaxation_scene(fig3):
    with pytest.raises(UserError, match="runs by load step"):
        DynamicTransient(build_model(fig3))


def test_both_solvers_through_the_contract_give_the_same_record_names(fig3):
    """Every name of STEP_KEYS, the same energy names, and the same shape and dtype per name;
    a name only one solver writes is the dynamic solver's own, documented in the UNITS table
    (append refuses any other)."""
    model = build_model(fig3)
    _, (static,) = drive(StaticSolver(model), initial_state(model), model.load_values)
    _, (dynamic,) = drive(DynamicSolver(model), initial_state(model), model.load_values)
    assert set(static) == set(STEP_KEYS) | energy_names(static) | {"stress"}  # fig3 has a weft:
    # the contract, nothing more
    assert energy_names(static) == energy_names(dynamic)
    assert set(static) <= set(dynamic)
    for name in static:
        assert np.shape(static[name]) == np.shape(dynamic[name]), name
        assert np.asarray(static[name]).dtype == np.asarray(dynamic[name]).dtype, name
        assert np.shape(static[name])[:1] == (model.yarn_count,), name
    for name in set(dynamic) - set(static):
        units_of(f"steps/{name}", model.control)  # raises for an undocumented name


def model_kinds() -> list[tuple[str, str]]:
    """(model, boundary) of every kind of model a scene can ask for: read from the scene
    schema's choices (geometry.model, and a fabric's geometry.boundary), not listed, so a
    new model is covered by construction."""
    keys = scene_keys()
    kinds = []
    for model in keys["geometry.model"].choices:
        boundaries = keys["geometry.boundary"].choices if model == "fabric" else ("",)
        kinds += [(model, boundary) for boundary in boundaries]
    return kinds


def small_scene(model: str, boundary: str):
    """A small scene of that kind, with friction, under force control, one load step."""
    if model == "fabric":
        return paper_patch_scene(2, 2, 4, boundary=boundary, friction=PAPER_FRICTION,
                                 load={"values": [0.1], "weft_values": [0.05]})
    return make_scene(geometry={"length": 0.02, "segments": 16, "crossings": 2,
                                "amplitude": 0.5e-3},
                      warp=PAPER_WARP, weft=PAPER_WEFT, friction=PAPER_FRICTION,
                      load={"values": [0.1]})


@pytest.mark.parametrize("name", ["static", "dynamic"])
@pytest.mark.parametrize("kind", model_kinds(), ids=lambda kind: "-".join(filter(None, kind)))
def test_every_model_and_method_keeps_the_contract(kind, name):
    """Every kind of model, each solver method through `dynfab.solvers.by_name.make_solver`: a
    `Solver` (not a `Transient`), whose step through the contract alone records every name of
    STEP_KEYS, each with its units (`dynfab.results.file.UNITS`), the energies the registry names,
    and the model's domain check passes."""
    model = build_model(small_scene(*kind))
    solver = make_solver(model, name)
    assert isinstance(solver, Solver) and not isinstance(solver, Transient)
    state, record = solver.step(model.initial_state(), model.step_load(0))
    assert set(STEP_KEYS) <= set(record)
    assert energy_names(record) == {registry.TERMS[registry.index(term)].dataset
                                    for term in registry.active_terms(model.scene)}
    for key in record:
        units_of(f"steps/{key}", model.control)  # raises for an undocumented name
    model.check_step(record)
    assert set(solver.attrs()) >= {"solver", f"{name}_accuracy"}


def test_transient_through_the_contract_yields_the_frame_names(relax):
    model = build_model(relax)
    frames = list(DynamicTransient(model).advance(initial_state(model)))
    assert [frame["time"] for frame in frames] == [0.0, 2e-4, 4e-4]  # 0, each interval, T
    for frame in frames:
        assert set(FRAME_KEYS) <= set(frame)
        assert set(frame) - set(FRAME_KEYS) == energy_names(frame) - {"energy/kinetic"}


class OnlyTheContract:
    """A Solver with nothing but the contract's members, delegating to a real solver."""

    def __init__(self, solver):
        self._solver, self.name = solver, solver.name

    def attrs(self) -> dict:
        return self._solver.attrs()

    def step(self, state, load):
        return self._solver.step(state, load)


def test_a_run_needs_nothing_of_a_solver_but_its_contract(fig3, monkeypatch):
    """The same run through a bare Solver: the same steps, bit for bit (same arithmetic)."""
    scene = with_key(fig3, "load.values", [0.001, 0.002])
    reference = run(scene, "static")
    monkeypatch.setattr(run_module, "make_solver",
                        lambda model, *args: OnlyTheContract(StaticSolver(model)))
    bare = run(scene, "static")
    assert set(bare.steps) == set(reference.steps)
    for name in bare.steps:
        if name not in MACHINE_TIMES:
            np.testing.assert_array_equal(bare.steps[name], reference.steps[name], err_msg=name)


def module_of(path: Path) -> str:
    """The dotted name of a package file (kernels/ installs as dynfab.kernels)."""
    parts = path.relative_to(ROOT).with_suffix("").parts
    parts = ("dynfab", *parts[1:]) if parts[0] == "kernels" else parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> set[str]:
    """Every module a file imports (also inside functions), as dotted names."""
    tree = ast.parse(path.read_text())
    names = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    names |= {f"{node.module}.{alias.name}" for node in ast.walk(tree)
              if isinstance(node, ast.ImportFrom) for alias in node.names}
    names |= {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import)
              for alias in node.names}
    return names


def package_files() -> dict[str, Path]:
    return {module_of(p): p for folder in ("dynfab", "kernels") for p in (ROOT / folder).rglob("*.py")}


def solver_modules(files: dict[str, Path]) -> set[str]:
    """The modules that define a solver: a class (not a contract) with `attrs` and `step` or
    `advance`, the members of `dynfab.solvers.contract.Solver` and `Transient`: found, not listed,
    so a new model's or method's solver is covered by construction."""
    found = set()
    for module, path in files.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef) and not any(
                    getattr(base, "id", None) == "Protocol" for base in node.bases):
                methods = {n.name for n in node.body if isinstance(n, ast.FunctionDef)}
                if "attrs" in methods and methods & {"step", "advance"}:
                    found.add(module)
    return found


def test_no_solver_module_imports_another():
    """The solvers share the model side, never each other: no module that defines a solver
    imports another such module, and no module a solver imports (the model side: model,
    loading, observables, certificate, assembly, ...) imports a solver. Only the factory
    `dynfab.solvers.by_name` names them all."""
    files = package_files()
    solvers = solver_modules(files)
    assert {"dynfab.solvers.static", "dynfab.solvers.dynamic"} <= solvers  # the search finds
                                                                           # today's at least
    for module in solvers:
        assert not imports_of(files[module]) & (solvers - {module}), module
    model_side = {name for module in solvers for name in imports_of(files[module])
                  if name in files and name not in solvers}
    for module in model_side - {"dynfab.solvers.by_name"}:
        assert not imports_of(files[module]) & solvers, module


def test_displacement_control_moves_the_end_to_u_and_spreads_the_increment(fig3):
    """x_N = x0_N + u; every node moves by (u - u_prev) x0_i / L in x; z unchanged."""
    model = build_model(fig3)
    state = initial_state(model)
    length = model.scene.geometry.length  # L [m]
    previous = 0.4e-3  # u of the previous step [m]
    yarns = model.per_yarn(state.positions)  # a view of the state's (n, 2)
    yarns[:, :, 0] += previous * yarns[:, :, 0] / length
    before = yarns.copy()
    u = 1e-3
    positions = prescribe_load(model, state, u)
    rest = model.stacked("rest_position")
    np.testing.assert_allclose(positions[:, -1, 0], rest[:, -1, 0] + u, rtol=0, atol=1e-18)
    # the increment u - u_prev [m] spread linearly; rounding of sums of ~0.1 m numbers: 1e-16 m
    np.testing.assert_allclose(positions[:, :, 0] - before[:, :, 0],
                               (u - previous) * rest[:, :, 0] / length, rtol=0, atol=1e-16)
    np.testing.assert_array_equal(positions[:, :, 1], before[:, :, 1])
    np.testing.assert_array_equal(model.per_yarn(state.positions), before)  # not modified


def test_force_control_starts_from_the_previous_positions(fig3):
    model = build_model(with_key(fig3, "load.control", "force"))
    state = initial_state(model)
    positions = prescribe_load(model, state, 0.3)
    np.testing.assert_array_equal(positions, model.per_yarn(state.positions))
    assert not np.shares_memory(positions, state.positions)


def test_transient_load_ramps_through_the_load_values(relax):
    """Piecewise linear through (0, 0) and (k T / n, value_k), held after T
    (docs/model.md section 5)."""
    model = build_model(with_key(relax, "load.values", [0.2, 0.6]))
    T = model.scene.dynamic.duration
    assert load_at_time(model, 0.0) == 0.0
    assert load_at_time(model, T / 4) == pytest.approx(0.1, rel=1e-15)
    assert load_at_time(model, T / 2) == pytest.approx(0.2, rel=1e-15)
    assert load_at_time(model, 3 * T / 4) == pytest.approx(0.4, rel=1e-15)
    assert load_at_time(model, T) == pytest.approx(0.6, rel=1e-15)
    assert load_at_time(model, 2 * T) == pytest.approx(0.6, rel=1e-15)
