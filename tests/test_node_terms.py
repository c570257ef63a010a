"""A new term added through the registry and its element module alone, on every model, static
and dynamic (docs/model.md, "Node terms"; issue 36's done-when).

The term: a linear spring of stiffness K from each node to its as-woven place,
e_i = K |x_i - X_i|^2 / 2. It exists only as a module (`TETHER`: its numba element and its
Warp form) and one registry entry, made in a fresh process (its own numba cache: the
assemblies compiled with the term must not reach the other tests). Nothing else of dynfab is
edited: the builders attach its parameters, the one-yarn, planar and spatial assemblies and the
kernels sum it, every model records steps/energy/tether.

Checked on the paper's yarn, a clamped 2 x 2 patch and a 30 x 60 mm bias specimen, each one
load step from the as-woven state:
- the static step is an equilibrium of the rest of the model with the spring: at the step's
  positions x*, dV_rest/dx + K (x* - X) = 0 on every free dof, V_rest the model's energy
  without the term (its gradient from the model's own assembly), K (x* - X) written here from
  the formula; to the step's residual (its convergence tolerance) plus rounding (64 eps of the
  largest force term). Yarn and patch are frictionless, so V_rest's gradient needs no anchors.
  The specimen carries friction, so there the recorded energy/tether is checked instead:
  sum_i K |x_i - X_i|^2 / 2 from the step's positions, to 1e-12 relative (one sum in another
  order);
- the term acts: the step's positions move from the ones without it by more than 100 times
  both runs' error bounds;
- the dynamic solver (Warp kernels, which compile the term in) reaches the static step: every
  position within the two runs' error bounds (`steps/error_estimate`, tests/test_shear_dynamic.py
  explains the bound).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytest.importorskip("warp")

K = 20.0
"""The spring's stiffness [N/m]: against the paper yarn's EA / l0 = 2,200 N/m and the specimen's
stiffest springs it moves every model's step visibly while leaving it well posed."""

TETHER = f'''
"""A test node term: a spring of stiffness K [N/m] from each node to its as-woven place."""
from types import SimpleNamespace

import numba
import numpy as np
import warp as wp

K = {K!r}
PARAMETERS = ("stiffness",)


def parameters(scene, structure):
    return np.full((structure.rest_position.shape[0], 1), K)


@numba.njit(cache=True)
def energy(x, rest, p):
    total = 0.0
    for a in range(x.size):
        total += (x[a] - rest[a]) ** 2
    return 0.5 * p[0] * total


@numba.njit(cache=True)
def add_gradient(x, rest, p, g):
    for a in range(x.size):
        g[a] += p[0] * (x[a] - rest[a])


@numba.njit(cache=True)
def add_hessian(x, rest, p, H):
    for a in range(x.size):
        H[a, a] += p[0]


def warp(scalar, vec):
    @wp.func
    def force(x: vec, rest: vec, p: wp.array2d(dtype=scalar), i: int, first: int) -> vec:
        return -p[i, first] * (x - rest)

    @wp.func
    def energy(x: vec, rest: vec, p: wp.array2d(dtype=scalar), i: int, first: int) -> scalar:
        d = x - rest
        return scalar(0.5) * p[i, first] * wp.dot(d, d)

    @wp.func
    def stiffness(x: vec, rest: vec, p: wp.array2d(dtype=scalar), i: int,
                  first: int) -> scalar:
        return p[i, first]

    return SimpleNamespace(force=force, energy=energy, stiffness=stiffness)
'''

SCRIPT = r'''
import json
import sys

import numpy as np

sys.path.insert(0, sys.argv[1])
sys.path.insert(0, sys.argv[2])
import tether
sys.modules["dynfab.model.terms.tether"] = tether
from dynfab.model.terms import registry

ON = [True]
registry.TERMS += (registry.Term("tether", "a spring to the as-woven place (test)",
                                 lambda scene: ON[0], "energy/tether", yarn=False, node=True),)
registry.NAMES += ("tether",)

from dynfab.model import build_model
from dynfab.model.terms.kinematics import terms_of
from dynfab.reports.fabric_data import paper_patch_scene
from dynfab.scene import parse_scene_text
from dynfab.solvers.by_name import make_solver
from independent import make_scene
from test_shear_dynamic import SMALL_BIAS
from test_shear_specimens import HOLDING_FRICTION, scene_text

SCENES = {
    "yarn": make_scene(
        geometry=dict(length=0.1, segments=32, crossings=4, amplitude=0.5e-3),
        warp=dict(EA=13.72, EI=1.47e-7, kawabata_C=0.2e-3, kawabata_K=0.2),
        weft=dict(EI=1.47e-7, amplitude=0.5e-3, kawabata_C=0.2e-3, kawabata_K=0.2),
        load=dict(control="displacement", values=[2e-4])),
    "patch": paper_patch_scene(2, 2, load=dict(control="displacement", values=[2e-4],
                                                weft_values=[1e-4])),
    "bias": parse_scene_text(scene_text(SMALL_BIAS, [2e-3], HOLDING_FRICTION)),
}


def flat(positions, dim):
    return np.asarray(positions, float).reshape(-1, dim)


def path(model, solver):
    """The last step's (positions (n, dim), record) from the as-woven state."""
    state = model.initial_state()
    for index in range(len(model.load_values)):
        state, record = solver.step(state, model.step_load(index))
    return flat(state.positions, model.structure.rest_position.shape[1]), record


def rest_gradient(model, pos):
    """dV/dx of the model without the node term, frictionless, by its own assembly."""
    s = model.structure
    without = s._replace(node_term_active=np.zeros_like(s.node_term_active))
    grad = np.zeros_like(pos)
    terms_of(s).gradient(pos, without, np.zeros(s.chain_start.size - 1),
                         np.zeros((s.tie_a.size, 3)), np.zeros(s.tie_a.size), grad)
    return grad


out = {}
for name, scene in SCENES.items():
    ON[0] = False
    plain = build_model(scene)
    x_plain, plain_record = path(plain, make_solver(plain, "static"))
    ON[0] = True
    model = build_model(scene)
    s = model.structure
    x_static, static = path(model, make_solver(model, "static"))
    x_dynamic, dynamic = path(model, make_solver(model, "dynamic"))
    case = {"tethered": bool(s.node_term_active.any()),
            "bounds": float(np.max(static["error_estimate"]) + np.max(dynamic["error_estimate"])),
            "plain_bound": float(np.max(plain_record["error_estimate"])),
            "dynamic_difference": float(np.abs(x_dynamic - x_static).max()),
            "moved": float(np.abs(x_static - x_plain).max()),
            "recorded": float(np.sum(static["energy/tether"])),
            "energy": float(0.5 * tether.K * np.sum((x_static - s.rest_position) ** 2))}
    if not s.has_friction:
        free = ~s.fixed.reshape(x_static.shape)
        rest = rest_gradient(model, x_static)
        spring = tether.K * (x_static - s.rest_position)
        case["equilibrium"] = float(np.abs((rest + spring)[free]).max())
        case["residual"] = float(np.max(static["residual"]))
        case["force_scale"] = float(np.abs(rest[free]).max())
    out[name] = case
print(json.dumps(out))
'''


@pytest.fixture(scope="module")
def tethered(tmp_path_factory):
    """Each model's figures (the script's JSON), from one process with the term registered."""
    folder = tmp_path_factory.mktemp("tether")
    (folder / "tether.py").write_text(textwrap.dedent(TETHER))
    script = folder / "run_tethered.py"
    script.write_text(SCRIPT)
    tests = os.path.dirname(os.path.abspath(__file__))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(folder / "numba_cache"))
    done = subprocess.run([sys.executable, str(script), str(folder), tests], env=env,
                          capture_output=True, text=True, timeout=1500)
    assert done.returncode == 0, done.stderr[-4000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("name", ["yarn", "patch", "bias"])
def test_a_new_node_term_reaches_every_model_static_and_dynamic(tethered, name):
    case = tethered[name]
    assert case["tethered"]
    assert case["moved"] > 100 * max(case["bounds"], case["plain_bound"])  # the term acts
    assert case["dynamic_difference"] <= case["bounds"]
    if "equilibrium" in case:  # frictionless: the rest of the model balances the spring
        eps = np.finfo(float).eps
        assert case["equilibrium"] <= case["residual"] + 64 * eps * case["force_scale"]
    else:
        assert case["recorded"] == pytest.approx(case["energy"], rel=1e-12)
    assert case["recorded"] == pytest.approx(case["energy"], rel=1e-12)


TWO_TERMS = r"""
import json
from types import SimpleNamespace

import numpy as np
import warp as wp

from dynfab.model.terms import nodes


def term(scale):
    def warp(scalar, vec):
        @wp.func
        def force(x: vec, rest: vec, p: wp.array2d(dtype=scalar), i: int, first: int) -> vec:
            return -p[i, first] * scalar(scale) * (x - rest)

        @wp.func
        def energy(x: vec, rest: vec, p: wp.array2d(dtype=scalar), i: int, first: int) -> scalar:
            return scalar(0.5 * scale) * p[i, first] * wp.dot(x - rest, x - rest)

        @wp.func
        def stiffness(x: vec, rest: vec, p: wp.array2d(dtype=scalar), i: int,
                      first: int) -> scalar:
            return p[i, first] * scalar(scale)
        return SimpleNamespace(force=force, energy=energy, stiffness=stiffness)
    return SimpleNamespace(warp=warp, PARAMETERS=("k",))


nodes.MODULES = (term(1.0), term(10.0), term(100.0))
from dynfab.kernels import node_terms, structure_arrays
from dynfab.kernels.precision import vector

vec = vector(wp.float64, 2)
Data = structure_arrays.struct(wp.float64, 2)
summed = node_terms.functions(wp.float64, 2)


@wp.kernel
def probe(pos: wp.array(dtype=vec), data: Data, force: wp.array(dtype=vec),
          energy: wp.array(dtype=wp.float64), rows: wp.array(dtype=wp.float64)):
    i = wp.tid()
    force[i] = summed.force(i, pos, data)
    energy[i] = summed.energy(i, pos, data)
    rows[i] = summed.stiffness(i, pos, data)


data = Data()
for name, field in Data.vars.items():
    setattr(data, name, wp.zeros((1,) * field.type.ndim, dtype=field.type.dtype))
data.rest_position = wp.array(np.zeros((2, 2)), dtype=vec)
data.node_parameters = wp.array(np.array([[2.0, 3.0], [5.0, 7.0]]), dtype=wp.float64)
data.node_term_first = wp.array(np.array([0, -1, 1], np.int32), dtype=wp.int32)
pos = wp.array(np.array([[1.0, -2.0], [0.5, 0.25]]), dtype=vec)
out = [wp.zeros(2, dtype=vec), wp.zeros(2, dtype=wp.float64), wp.zeros(2, dtype=wp.float64)]
wp.launch(probe, dim=2, inputs=[pos, data, *out])
print(json.dumps([a.numpy().tolist() for a in out]))
"""


def test_the_kernels_sum_every_registered_node_term_where_the_structure_has_it(tmp_path):
    """Three node terms registered, the second absent from the structure (its column -1): each
    node's force, energy and stiffness bound are the sums of the first's and the third's,
    e = s k |x - X|^2 / 2 with s = 1 and 100, k its parameter column (exact in binary
    floating point for these values)."""
    script = tmp_path / "two_terms.py"
    script.write_text(TWO_TERMS)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-4000:]
    force, energy, rows = (np.array(a) for a in json.loads(done.stdout.strip().splitlines()[-1]))
    x = np.array([[1.0, -2.0], [0.5, 0.25]])
    k = np.array([[2.0, 3.0], [5.0, 7.0]]) * [1.0, 100.0]  # (node, term): s k
    np.testing.assert_array_equal(force, -k.sum(axis=1)[:, None] * x)
    np.testing.assert_array_equal(energy, 0.5 * k.sum(axis=1) * (x ** 2).sum(axis=1))
    np.testing.assert_array_equal(rows, k.sum(axis=1))
