"""The one data model (`dynfab.model.structure`): both models' scenes are chains, ties and held dofs
(docs/model.md, "The structure"). Expected values come from the scene's own numbers and the
geometry of docs/model.md sections 1 and 10, not from the builders."""

import numpy as np
from independent import PAPER_FRICTION, PAPER_WARP, PAPER_WEFT, make_scene, pullout_scene

from dynfab.model.builders import build_structure
from dynfab.scene import load_scene
from dynfab.model.structure import GROUND, chain_count, chain_nodes, chain_ties, grounded


def closures(structure, positions):
    """g = c - sigma (z_a - z_b) of every tie, z_b = 0 for ground (docs/model.md sections 3, 10)."""
    z_a = positions[structure.tie_a, -1]
    z_b = np.where(structure.tie_b == GROUND, 0.0, positions[structure.tie_b, -1])
    return structure.tie_gap_offset - structure.tie_side * (z_a - z_b)


def test_a_one_yarn_sweep_is_independent_chains_tied_to_ground():
    scene = make_scene(geometry={"length": 0.1, "segments": 32, "crossings": 4,
                                 "amplitude": 0.5e-3},
                       warp=PAPER_WARP, weft=PAPER_WEFT, friction=PAPER_FRICTION,
                       load={"values": [0.1]}, sweep={"warp.EA": [10.0, 20.0, 30.0]})
    s = build_structure(scene)
    assert chain_count(s) == 3 and grounded(s)
    assert np.all(s.tie_b == GROUND) and s.tie_a.size == 3 * 4
    for y, EA in enumerate((10.0, 20.0, 30.0)):
        nodes = chain_nodes(s, y)
        segments = slice(nodes.start - y, nodes.stop - y - 1)
        np.testing.assert_allclose(s.stretch_stiffness[segments] * s.rest_length[segments], EA,
                                   rtol=1e-15)
        ties = chain_ties(s, y)  # crossing j at node (2j - 1) N / (2 N_we), docs/model.md section 1
        assert list(s.tie_a[ties] - nodes.start) == [4, 12, 20, 28]
        # default k_t = EA / (L / N) of each yarn (docs/model.md section 4)
        np.testing.assert_allclose(s.tie_friction_law[ties, 3], EA * 32 / 0.1, rtol=1e-15)
    # as woven, every contact starts at g = 0 (docs/model.md section 3)
    np.testing.assert_array_equal(closures(s, s.rest_position), 0.0)
    # node 0 pinned, z_N held, x_N loaded (force control)
    fixed = s.fixed.reshape(-1, 2)
    assert fixed.sum() == 3 * 3 and not fixed[s.load_node, 0].any()


def test_a_fabric_patch_ties_warp_and_weft_nodes_at_every_crossing():
    s = build_structure(load_scene("runs/fabric_strip.toml"))
    warps = int(np.sum(s.chain_family == 0))
    wefts = chain_count(s) - warps
    assert not grounded(s) and s.tie_a.size == warps * wefts
    start = s.chain_start
    chain_of = np.repeat(np.arange(chain_count(s)), np.diff(start))
    k, j = np.divmod(np.arange(s.tie_a.size), wefts)  # crossing c = k n_we + j
    np.testing.assert_array_equal(chain_of[s.tie_a], k)
    np.testing.assert_array_equal(chain_of[s.tie_b], warps + j)
    np.testing.assert_array_equal(closures(s, s.rest_position), 0.0)
    # the warp lies on side (-1)^(k + j), above where its as-woven z exceeds the weft's
    above = s.rest_position[s.tie_a, 1] > s.rest_position[s.tie_b, 1]
    np.testing.assert_array_equal(np.where(above, 1.0, -1.0), s.tie_side)
    # the planes X_j, Y_k through the crossing nodes as woven (docs/model.md section 10)
    np.testing.assert_allclose(s.tie_plane[:, 0], s.rest_position[s.tie_a, 0], atol=1e-15)
    np.testing.assert_allclose(s.tie_plane[:, 1], s.rest_position[s.tie_b, 0], atol=1e-15)


def test_masses_add_up_to_the_yarns_weight():
    """sum_i rho_l lbar_i = rho_l x the chain's arc length (docs/model.md section 5)."""
    s = build_structure(pullout_scene())
    for y in range(chain_count(s)):
        nodes = chain_nodes(s, y)
        segments = slice(nodes.start - y, nodes.stop - y - 1)
        arc = np.hypot(*np.diff(s.rest_position[nodes], axis=0).T).sum()
        np.testing.assert_allclose(s.rest_length[segments].sum(), arc, rtol=1e-14)
        rho = s.mass[nodes].sum() / arc
        np.testing.assert_allclose(s.mass[nodes] / rho, np.r_[s.rest_length[segments], 0] / 2
                                   + np.r_[0, s.rest_length[segments]] / 2, rtol=1e-12)
