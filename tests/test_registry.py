"""The term registry (dynfab/model/terms/registry.py) drives the numba assembly and the reported
energies.

- Terms switched off in a yarn (`Yarn.active`) add nothing, and the others add their
  docs/model.md energies: the energy vector holds 0 for the former and each closed form
  (tests/independent.py, `yarn_energies`) for the latter; the gradient is the central
  difference of the sum of the active terms' closed forms, the Hessian that of the gradient.
  (That every registry term's entry points are the ones the assembly calls is what this
  check and tests/test_terms.py, every term's energy at its registry index against its
  closed form and the total gradient and Hessian against central differences, show from
  outside; the registry's own tuples are not compared with themselves.)
- The energies a step reports are the registry datasets of the model's terms, and
  friction's `energy/stick` is the stick springs' energy 1/2 k_t (x - xi)^2 after the
  return map (docs/model.md section 4), as written independently here.
- A new term is its own module and one registry entry: a term declared only that way (a
  test module and an entry added at run time, in a separate process with its own numba
  cache) appears in the energy vector, the gradient, the Hessian and the result datasets.
"""
import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from dynfab.model import assembly
from dynfab.linalg.banded import zeros_band
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.model.observables import finish_step
from dynfab.model.terms import registry
from dynfab.model.terms.friction import INDEX as FRICTION
from independent import (EPS, contact_forces, dense, fd_gradient, fd_jacobian, scene_gralen,
                         yarn_energies)

PAPER_TABLES = dict(
    geometry=dict(length=0.1, segments=16, crossings=4, amplitude=0.5e-3, yarns=2),
    warp=dict(EA=13.72, EI=1.47e-7, kawabata_C=0.2e-3, kawabata_K=0.2, linear_density=3e-5),
    weft=dict(EI=1.47e-7, amplitude=0.5e-3, kawabata_C=0.2e-3, kawabata_K=0.2, count=16),
)
FRICTION_TABLE = dict(alpha=0.2, beta=1e3, contact_length=2e-3, fiber_radius=1e-3)


def all_terms_scene(make_scene, values=(0.05,)):
    """Every term on: contact, friction, gravity and a force-controlled load."""
    return make_scene(**PAPER_TABLES, friction=FRICTION_TABLE, gravity=dict(g=9.81),
                      load=dict(control="force", values=list(values)))


def perturbed(yarn, seed):
    """The as-woven positions moved by up to 2 % of a segment (seeded), the crossings then
    placed at closures g = (1e-5, 1e-4, -1e-5, 5e-5) m (g = c_j - s_j z, docs/model.md section 3):
    three closed, one open; every term has a nonzero gradient."""
    rng = np.random.default_rng(seed)
    l0 = yarn.rest_length.mean()
    pos = yarn.rest_position + rng.uniform(-0.02, 0.02, yarn.rest_position.shape) * l0
    closure = np.array([1e-5, 1e-4, -1e-5, 5e-5])
    pos[yarn.crossing_node, 1] = yarn.crossing_side * (yarn.gap_offset - closure)
    return pos


@pytest.mark.parametrize("switched_off", [(), ("friction",), ("contact", "gravity", "load")])
def test_switched_off_terms_add_nothing_and_the_others_their_closed_forms(make_scene,
                                                                           switched_off):
    # Tolerances as in tests/test_terms.py: energies to 1e-11 relative (its rounding budget);
    # a central difference with step h (as rounded) errs by eps S / h (S = n |E| + sum |dE/dr_i|
    # |r_i|) plus h^2 K / (6 ell) for a gradient, eps K r / h plus h^2 K / (6 ell^2) for a
    # Hessian, K bounding the stiffness (2 EA/l0 + 16 EI/(lbar l0^2) + k_we + k_t, all terms)
    # and ell the length over which it varies (l0, or the contact law's); asserted with a
    # factor 10. The friction limits are frozen at Gralen's law of the closed-form contact
    # forces (independent of the contact term being on).
    scene = all_terms_scene(make_scene)
    yarn = build_model(scene).yarns[0]
    active = yarn.active.copy()
    for name in switched_off:
        active[registry.index(name)] = False
    yarn = yarn._replace(active=active)
    on = [term.name for term, a in zip(registry.TERMS, active) if a]
    pos = perturbed(yarn, seed=7)
    P, anchors = 0.05, pos[yarn.crossing_node, 0] - 1e-7
    limit = scene_gralen(scene, contact_forces(scene, pos))
    assert (limit > 0).any() and (limit == 0).any()  # closed and open crossings

    def closed_forms(r):
        return yarn_energies(scene, r, 1.0, P, anchors, limit)

    energies = assembly.energy_vector()
    assembly.energies(pos, yarn, P, anchors, limit, energies)
    expected = closed_forms(pos)
    for k, term in enumerate(registry.TERMS):
        if term.name in on:
            assert expected[term.name] != 0.0, term.name  # every active term is exercised
            assert energies[k] == pytest.approx(expected[term.name], rel=1e-11, abs=0), term.name
        else:
            assert energies[k] == 0.0, term.name

    def gradient(r):
        out = np.zeros_like(r)
        assembly.gradient(r, yarn, P, anchors, limit, out)
        return out

    law, l0 = yarn.contact_law, scene.geometry.length / scene.geometry.segments
    K = (2 * yarn.stretch_stiffness.max() + 16 * yarn.bend_stiffness.max() / l0 ** 2 + law[0]
         + yarn.stick_stiffness)
    ell = min(l0, 1.0 / (law[0] ** 2 * (law[1] * law[2] ** 2 + law[3] * law[4] ** 2)))
    h = 1e-6 * l0
    total = lambda r: sum(closed_forms(r)[name] for name in on)
    fd = fd_gradient(total, pos, h)
    S = (6 + 2 * pos.shape[0]) * abs(total(pos)) + np.sum(np.abs(fd) * np.abs(pos))
    tolerance = 10 * (EPS * S / h + h ** 2 * K / (6 * ell))
    assert np.abs(fd).max() > 1e3 * tolerance
    assert np.abs(gradient(pos) - fd).max() <= tolerance

    h = 1e-5 * l0
    band = zeros_band(pos.size)
    c = yarn.crossing_node.size
    assembly.hessian(pos, yarn, anchors, limit, np.zeros(c), False, band)
    fd = fd_jacobian(gradient, pos, h)
    tolerance = 10 * (EPS * K * np.abs(pos).max() / h + h ** 2 * K / (6 * ell ** 2))
    assert np.abs(fd).max() > 1e3 * tolerance
    assert np.abs(dense(band) - fd).max() <= tolerance


def test_reported_energies_are_the_registry_datasets(make_scene):
    # A step reports steps/energy/<term> for exactly the model's terms (Term.dataset): on a
    # yarn with every term, every term with one-yarn entry points (Term.yarn);
    # friction's is its stick springs after the return map: sum_j 1/2 k_t (x_nj - xi_j)^2.
    # Each crossing's value is the Huber energy on the stick branch, or on the slide
    # branch exactly at |s| = F_T / k_t, equal to the quadratic up to a few eps; summed
    # over 4 crossings and 2 yarns: 1e-13 relative.
    model = build_model(all_terms_scene(make_scene))
    state = initial_state(model)
    positions = np.stack([perturbed(y, seed=k) for k, y in enumerate(model.yarns)])
    nodes = model.yarns[0].crossing_node
    # two crossings 1e-7 m from their anchors, within F_T / k_t >= beta ell r_f / k_t = 9e-7 m
    # where closed: they stick; the others, 1e-4 m away, slide
    anchors = model.per_crossing(state.anchors)
    anchors[:, :2] = positions[:, nodes[:2], 0] - 1e-7
    state.anchors[:, 0] = anchors.ravel()
    _, record = finish_step(model, state, positions, 0.05, np.zeros(2), np.zeros(2, np.int64))
    reported = {name for name in record if name.startswith("energy/")}
    assert reported == {t.dataset for t in registry.TERMS if t.yarn}
    assert record["sliding"].any() and not record["sliding"].all()  # both friction regimes
    slip = positions[:, nodes, 0] - record["anchors"]
    k_t = np.array([y.stick_stiffness for y in model.yarns])
    stick = 0.5 * k_t * (slip ** 2).sum(axis=1)
    assert record["energy/stick"] == pytest.approx(stick, rel=1e-13, abs=0)

    elastic = build_model(make_scene(**PAPER_TABLES, load=dict(control="displacement",
                                                                values=[1e-4])))
    _, record = finish_step(elastic, initial_state(elastic), positions, 1e-4, np.zeros(2),
                            np.zeros(2, np.int64))
    assert {name for name in record if name.startswith("energy/")} == \
        {"energy/stretch", "energy/bending", "energy/contact"}
    assert not elastic.yarns[0].active[FRICTION]


TETHER = '''
"""A test term: a spring of stiffness K [N/m] holding the middle node at its rest height."""
import numba

from dynfab.linalg.banded import band_add

K = 50.0


@numba.njit(cache=True)
def yarn_energy(pos, yarn, frozen):
    m = pos.shape[0] // 2
    dz = pos[m, 1] - yarn.rest_position[m, 1]
    return 0.5 * K * dz * dz


@numba.njit(cache=True)
def add_yarn_gradient(pos, yarn, frozen, grad):
    m = pos.shape[0] // 2
    grad[m, 1] += K * (pos[m, 1] - yarn.rest_position[m, 1])


@numba.njit(cache=True)
def add_yarn_hessian(pos, yarn, frozen, band):
    m = pos.shape[0] // 2
    band_add(band, 2 * m + 1, 2 * m + 1, K)
'''

NEW_TERM_SCRIPT = '''
import json
import sys
import numpy as np
sys.path.insert(0, sys.argv[1])
import tether
sys.modules["dynfab.model.terms.tether"] = tether
from dynfab.model.terms import registry
before = len(registry.TERMS)
registry.TERMS += (registry.Term("tether", "test spring", lambda scene: True, "energy/tether"),)
registry.NAMES += ("tether",)
tethered = registry.index("tether")

from dynfab.model import assembly
from dynfab.linalg.banded import zeros_band, BANDWIDTH
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.model.observables import finish_step
from dynfab.scene import parse_scene_text
sys.path.insert(0, sys.argv[2])
from independent import scene_toml

scene = parse_scene_text(scene_toml({
    "geometry": dict(length=0.1, segments=16, crossings=0, amplitude=0.0),
    "warp": dict(EA=13.72, EI=1.47e-7, kawabata_C=0.2e-3, kawabata_K=0.2),
    "load": dict(control="displacement", values=[1e-4])}))
model = build_model(scene)
yarn = model.yarns[0]
pos = yarn.rest_position.copy()
m = pos.shape[0] // 2
pos[m, 1] += 1e-4
zero = np.zeros(0)
vector = assembly.energy_vector()
assembly.energies(pos, yarn, 0.0, zero, zero, vector)
grad = np.zeros_like(pos)
assembly.gradient(pos, yarn, 0.0, zero, zero, grad)
without = np.zeros_like(pos)
yarn_without = yarn._replace(active=yarn.active & (np.arange(yarn.active.size) != tethered))
assembly.gradient(pos, yarn_without, 0.0, zero, zero, without)
band, band_without = zeros_band(pos.size), zeros_band(pos.size)
assembly.hessian(pos, yarn, zero, zero, zero, False, band)
assembly.hessian(pos, yarn_without, zero, zero, zero, False, band_without)
_, record = finish_step(model, initial_state(model), pos[None], 1e-4, np.zeros(1),
                        np.zeros(1, np.int64))
try:  # a yarn built for another term list (as after a stale numba cache) is refused
    assembly.energies(pos, yarn._replace(active=yarn.active[:before]), 0.0, zero, zero, vector)
    refused = False
except RuntimeError:
    refused = True
print(json.dumps({"terms": model.terms, "refused": refused, "added": int(vector.size) - before,
                  "energy": vector[tethered],
                  "dz": pos[m, 1] - yarn.rest_position[m, 1],
                  "force": grad[m, 1] - without[m, 1],
                  "others_force": without[m, 1],
                  "stiffness": band[2 * m + 1, BANDWIDTH] - band_without[2 * m + 1, BANDWIDTH],
                  "others_stiffness": band_without[2 * m + 1, BANDWIDTH],
                  "reported": record["energy/tether"][0]}))
'''


def test_a_new_term_is_its_module_and_one_registry_entry(tmp_path):
    # The tether term exists only as a module and a registry entry: it shows up in the energy
    # vector's last entry, the gradient, the Hessian and the step's energy/tether, with
    # E = K dz^2 / 2, dE/dz = K dz, d2E/dz2 = K (dz = 1e-4 m at the middle node). The energy
    # is the same floating-point product as here; force and stiffness are read as differences
    # of sums that include the other terms, so they carry those sums' rounding, eps x |sum|.
    (tmp_path / "tether.py").write_text(textwrap.dedent(TETHER))
    script = tmp_path / "new_term.py"
    script.write_text(NEW_TERM_SCRIPT)
    tests = os.path.dirname(os.path.abspath(__file__))
    # its own numba cache: the assembly compiled with the tether must not reach the others
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba_cache"))
    done = subprocess.run([sys.executable, str(script), str(tmp_path), tests], env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert "tether" in out["terms"] and out["added"] == 1
    assert out["refused"]
    K, dz = 50.0, out["dz"]
    assert dz == pytest.approx(1e-4, rel=1e-9)
    assert out["energy"] == out["reported"] == 0.5 * K * dz * dz
    eps = np.finfo(float).eps
    force_sum = abs(out["force"]) + abs(out["others_force"])
    assert abs(out["force"] - K * dz) <= 4 * eps * force_sum
    stiffness_sum = abs(out["stiffness"]) + abs(out["others_stiffness"])
    assert abs(out["stiffness"] - K) <= 4 * eps * stiffness_sum
