"""The shear specimens' layout (dynfab.model.specimen_layout, docs/model.md section 11): yarns,
nodes, crossings, held nodes and zones against hand counts and the geometric definitions,
and the nominal kinematics against closed forms (Cao et al. 2008 eqs. 1-2 and 13)."""

import math

import numpy as np
import pytest

from dynfab.errors import UserError
from dynfab.model.specimen_layout import (
    bias_extension, bias_limit, frame_map, held_positions, held_velocity, nominal_shear_angle,
    picture_frame, shear_angles)

EPS = np.finfo(float).eps
W, H, SPACING = 0.06, 0.12, 5.18e-3
"""The issue's bias specimen [m] (Cao's fabric: 1.93 yarns/cm)."""
A_WARP, A_WEFT = 0.3e-3, 0.2e-3
"""Unequal amplitudes [m], so a swapped family shows."""
N = 4
"""Segments between consecutive crossings."""
YARN_WIDTHS = (4.2e-3, 3.0e-3)
"""Warp and weft widths [m] (Cao's 4.2 mm; unequal, so a swapped family shows)."""


@pytest.fixture(scope="module")
def bias():
    return bias_extension(W, H, SPACING, SPACING, A_WARP, A_WEFT, N, YARN_WIDTHS)


@pytest.fixture(scope="module")
def bias_unequal():
    """Unequal spacings, so a swapped pitch or spacing shows."""
    return bias_extension(W, H, 5.18e-3, 6.1e-3, A_WARP, A_WEFT, N, YARN_WIDTHS)


@pytest.fixture(scope="module")
def frame():
    """L = 60 mm, warp spacing 10 mm, weft spacing 12 mm (hand counts below)."""
    return picture_frame(0.06, 0.01, 0.012, A_WARP, A_WEFT, N)


def chains(layout):
    return [np.arange(a, b) for a, b in zip(layout.chain_start[:-1], layout.chain_start[1:])]


def pitch(layout, family, warp_spacing, weft_spacing):
    """Arc between a yarn's consecutive crossings: a warp crosses wefts weft_spacing apart."""
    return weft_spacing if family == 0 else warp_spacing


def layouts_with_spacings(bias, bias_unequal, frame):
    return [(bias, SPACING, SPACING), (bias_unequal, 5.18e-3, 6.1e-3), (frame, 0.01, 0.012)]


# --------------------------------------------------------------------------
# Counts by hand.


def test_frame_counts_by_hand(frame):
    # Warps at y = 30 + 10 k mm, kept strictly farther than half a weft segment (10/4/2 mm)
    # from the bars: k = -2..2 (k = +-3 lies on a bar). Wefts at x = 30 + 12 j mm, |12 j| <
    # 30 - 1.5: j = -2..2. A warp: crossings at x = 6..54 mm, 4 pitches of 12 mm x 4 segments
    # plus end pieces of 6 mm = 2 segments of 3 mm each: 20 segments, 21 nodes. A weft:
    # crossings at y = 10..50, 4 x 4 segments plus 10 mm end pieces = 4 segments each: 24
    # segments, 25 nodes. 5 x 21 + 5 x 25 = 230 nodes, 25 crossings, 20 pinned ends, lateral
    # stencils: 4 neighbouring pairs x 5 crossing yarns per family = 40.
    assert frame.positions.shape == (230, 3)
    assert list(frame.chain_family) == [0] * 5 + [1] * 5
    assert list(frame.chain_index) == [-2, -1, 0, 1, 2] * 2
    assert list(np.diff(frame.chain_start)) == [21] * 5 + [25] * 5
    assert frame.crossing_nodes.shape == (25, 2)
    assert frame.held[chain_ends(frame)].sum() == 20
    assert frame.lateral.shape == (40, 4)
    assert np.all(frame.zone == 0)
    # Interior: neither yarn's first or last crossing: k, j in -1..1.
    assert frame.interior.sum() == 9
    assert np.all(np.abs(frame.crossing_lattice[frame.interior]) <= 1)


def test_frame_drops_a_yarn_on_a_bar():
    # Equal 10 mm spacings on L = 60 mm: yarns k = +-3 lie on the bars and are dropped;
    # each kept yarn: 4 x 4 segments plus two 10 mm end pieces of 4 segments: 25 nodes.
    layout = picture_frame(0.06, 0.01, 0.01, A_WARP, A_WEFT, N)
    assert list(np.diff(layout.chain_start)) == [25] * 10
    assert sorted(set(layout.chain_index)) == [-2, -1, 0, 1, 2]


def test_small_bias_counts_by_hand():
    # W = 20 mm, H = 40 mm, spacing s = 4.5 sqrt(2) mm: crossing (k, j) lies at the centre
    # (10, 20) mm + 4.5 mm (a, b), a = j - k, b = j + k, with |a| <= 2, |b| <= 4 of equal
    # parity: 15 + 8 = 23 points. Warps k = +-3 and wefts j = +-3 hold one each and are
    # dropped with it: 19 crossings on warps and wefts -2..2. Warp 0 runs through the centre
    # along (1, 1): it meets x = 0 and x = W at s = -+10 sqrt(2) mm; its crossings j = -2..2
    # lie at s = 4.5 sqrt(2) j mm, so each end piece is 1 sqrt(2) mm against a segment of
    # 4.5 sqrt(2) / 4 mm: 0.89 segment, kept as 1 segment: 4 x 4 + 2 = 18 segments, 19 nodes,
    # both ends on the long sides 10 mm from the clamps (free: a 4.2 mm band reaches 3 mm
    # along them).
    layout = bias_extension(0.02, 0.04, 4.5e-3 * math.sqrt(2), 4.5e-3 * math.sqrt(2),
                            A_WARP, A_WEFT, N, YARN_WIDTHS)
    assert layout.crossing_nodes.shape == (19, 2)
    assert list(layout.chain_index) == [-2, -1, 0, 1, 2] * 2
    warp0 = chains(layout)[2]
    assert warp0.size == 19
    ends = layout.positions[warp0[[0, -1]], :2]
    np.testing.assert_allclose(ends, [[0.0, 0.01], [0.02, 0.03]], rtol=0, atol=4 * EPS * 0.04)
    assert not layout.held[warp0].any()


def test_bias_crossings_match_a_direct_enumeration(bias):
    # Independent statement of the rule: every lattice point (k, j) inside the rectangle,
    # then yarns with fewer than two crossings dropped (with their crossings) until stable.
    centre, s = np.array([W / 2, H / 2]), SPACING / math.sqrt(2)
    points = {(k, j) for k in range(-40, 41) for j in range(-40, 41)
              if 0 <= centre[0] + s * (j - k) <= W and 0 <= centre[1] + s * (j + k) <= H}
    while True:
        warps = [k for k, _ in points]
        wefts = [j for _, j in points]
        kept = {(k, j) for k, j in points if warps.count(k) >= 2 and wefts.count(j) >= 2}
        if kept == points:
            break
        points = kept
    assert {tuple(c) for c in bias.crossing_lattice} == points
    assert len(points) == len(bias.crossing_lattice)


# --------------------------------------------------------------------------
# Geometry of the chains.


def test_crossing_nodes_coincide_in_plane_and_lie_two_amplitudes_apart(bias, bias_unequal,
                                                                        frame):
    # One formula places both nodes of a crossing, so x, y agree exactly; the warp lies
    # above where k + j is even, at +A_wa against the weft's -A_we, exactly (the sinusoid is
    # evaluated from the nearest crossing).
    for layout in (bias, bias_unequal, frame):
        warp, weft = layout.positions[layout.crossing_nodes.T]
        assert np.array_equal(warp[:, :2], weft[:, :2])
        even = layout.crossing_lattice.sum(axis=1) % 2 == 0
        assert np.array_equal(layout.crossing_side, np.where(even, 1.0, -1.0))
        np.testing.assert_array_equal(warp[:, 2], layout.crossing_side * A_WARP)
        np.testing.assert_array_equal(weft[:, 2], -layout.crossing_side * A_WEFT)
        assert np.array_equal(layout.chain_family[np.searchsorted(
            layout.chain_start, layout.crossing_nodes, side="right") - 1],
            np.tile([0, 1], (len(warp), 1)))


def test_consecutive_crossings_are_one_spacing_apart(bias, bias_unequal, frame):
    # Along a warp consecutive crossings are one weft spacing apart, along a weft one warp
    # spacing; rounding of positions ~ 0.1 m: 8 eps x 0.1 m.
    for layout, warp_spacing, weft_spacing in layouts_with_spacings(bias, bias_unequal, frame):
        for family in (0, 1):
            nodes = np.sort(layout.crossing_nodes[:, family])
            chain = np.searchsorted(layout.chain_start, nodes, side="right") - 1
            same = chain[1:] == chain[:-1]
            gap = np.linalg.norm(np.diff(layout.positions[nodes, :2], axis=0), axis=1)[same]
            np.testing.assert_allclose(gap, pitch(layout, family, warp_spacing, weft_spacing),
                                       rtol=0, atol=8 * EPS * 0.1)


def test_segments_are_a_pitch_over_n_between_crossings_and_at_most_that_at_the_ends(
        bias, bias_unequal, frame):
    # Between crossings a pitch holds N equal segments; end pieces are cut into equal
    # segments no longer than that and at least half of it (shorter ones were dropped).
    for layout, warp_spacing, weft_spacing in layouts_with_spacings(bias, bias_unequal, frame):
        crossing = np.zeros(layout.positions.shape[0], dtype=bool)
        crossing[layout.crossing_nodes.ravel()] = True
        for family, nodes in zip(layout.chain_family, chains(layout)):
            segment = pitch(layout, family, warp_spacing, weft_spacing) / N
            length = np.linalg.norm(np.diff(layout.positions[nodes, :2], axis=0), axis=1)
            inner = np.flatnonzero(crossing[nodes])
            between = length[inner[0]:inner[-1]]
            np.testing.assert_allclose(between, segment, rtol=0, atol=8 * EPS * 0.1)
            ends = np.concatenate([length[:inner[0]], length[inner[-1]:]])
            assert np.all(ends <= segment * (1 + 1e-12))
            assert np.all(ends >= 0.5 * segment / (1 + 1e-12))


def test_every_node_follows_its_yarns_sinusoid(bias_unequal, frame):
    # z = +-A cos(pi s / p), s from the yarn's crossing at index 0 of the other family; the
    # sign makes the warp +A at (k, j) with k + j even. Checked from the node's in-plane
    # position; a rounding of s ~ 1e-17 m moves z by A pi/p x 1e-17: 1e-15 A.
    for layout, warp_spacing, weft_spacing in ((bias_unequal, 5.18e-3, 6.1e-3),
                                               (frame, 0.01, 0.012)):
        if layout.test == "bias_extension":
            centre, t = np.array([W / 2, H / 2]), [np.array([1.0, 1.0]) / math.sqrt(2),
                                                   np.array([-1.0, 1.0]) / math.sqrt(2)]
        else:
            centre, t = np.array([0.03, 0.03]), [np.array([1.0, 0.0]), np.array([0.0, 1.0])]
        for family, index, nodes in zip(layout.chain_family, layout.chain_index,
                                        chains(layout)):
            spacing = (warp_spacing, weft_spacing)[family]
            origin = centre + index * spacing * t[1 - family]
            s = (layout.positions[nodes, :2] - origin) @ t[family]
            p = pitch(layout, family, warp_spacing, weft_spacing)
            amplitude, sign = (A_WARP, 1.0) if family == 0 else (A_WEFT, -1.0)
            expected = sign * amplitude * (-1.0) ** index * np.cos(math.pi * s / p)
            np.testing.assert_allclose(layout.positions[nodes, 2], expected, rtol=0,
                                       atol=1e-9 * amplitude)


def test_chains_point_along_the_pull(bias, frame):
    # Every chord n-1 -> n+1 (end nodes: the node itself) has a positive component along
    # the pull: +y for the bias test, (1, 1)/sqrt(2) for the frame. In fact every chord lies
    # along its family's direction, at 45 degrees to the pull in both tests: cosine 1/sqrt 2.
    for layout, pull in ((bias, np.array([0.0, 1.0])),
                         (frame, np.array([1.0, 1.0]) / math.sqrt(2))):
        for nodes in chains(layout):
            chord = layout.positions[np.minimum(nodes + 1, nodes[-1]), :2] \
                - layout.positions[np.maximum(nodes - 1, nodes[0]), :2]
            cosine = chord @ pull / np.linalg.norm(chord, axis=1)
            np.testing.assert_allclose(cosine, math.sqrt(0.5), rtol=1e-12)


# --------------------------------------------------------------------------
# Held nodes and zones.


def chain_ends(layout):
    return np.concatenate([[n[0], n[-1]] for n in chains(layout)])


def band_reach(family):
    """How far along a long side a yarn's band reaches from its centreline's end: half its
    width over sin 45 degrees (the band's edge is a parallel line w/2 away, at 45 degrees to
    the side)."""
    return 0.5 * YARN_WIDTHS[family] * math.sqrt(2.0)


def test_bias_holds_the_yarn_ends_whose_band_reaches_a_clamp(bias, bias_unequal):
    for layout, spacing in ((bias, SPACING), (bias_unequal, 5.18e-3)):
        ends = chain_ends(layout)
        family = np.repeat(layout.chain_family, 2)
        x_end, y_end = layout.positions[ends, :2].T
        near_clamp = np.minimum(y_end, H - y_end)
        on_short = near_clamp <= 1e-9 * H
        on_long = np.minimum(x_end, W - x_end) <= 1e-9 * W
        reach = np.array([band_reach(f) for f in family])
        # Every end on a short side is held, and every end on a long side whose band reaches
        # the clamp there; every other end on a long side is free.
        assert np.all(layout.held[ends[on_short]])
        assert np.all(layout.held[ends[on_long & (near_clamp <= reach)]])
        assert not layout.held[ends[on_long & (near_clamp > reach)]].any()
        # An end on neither side is a crossing (its end piece dropped): held only within
        # half a segment of a short side or, near a corner, by its band.
        held_inside = ~(on_short | on_long) & layout.held[ends]
        assert np.all(near_clamp[held_inside]
                      <= np.maximum(0.5 * spacing / N, reach[held_inside]))
        # The band rule holds ends on the long sides that the line rule left free, free ends
        # remain, and both clamps hold nodes.
        assert (on_long & (near_clamp > 1e-9 * H) & layout.held[ends]).any()
        assert (on_long & ~layout.held[ends]).sum() > 0
        held_y = y_end[layout.held[ends]]
        assert (held_y < H / 2).any() and (held_y > H / 2).any()


def test_frame_pins_every_yarn_end_to_a_bar(frame):
    ends = chain_ends(frame)
    assert frame.held[ends].all()
    for family, nodes in zip(frame.chain_family, chains(frame)):
        along = frame.positions[nodes[[0, -1]], family]   # x for a warp, y for a weft
        np.testing.assert_array_equal(along, [0.0, 0.06])


def clamp_reaches(x, y, b_warp, b_weft):
    """The geometric zone definition: does each of the point's two yarn bands meet a short
    side inside the rectangle? A band reaches b = (w/2) / sin 45 deg to either side of its
    centreline along a short side. Warp along (1, 1): its line meets y = 0 at x - y, y = H
    at x + H - y; weft along (-1, 1): y = 0 at x + y, y = H at x - (H - y)."""
    def meets(at, b):
        return (at >= -b) & (at <= W + b)
    warp = meets(x - y, b_warp) | meets(x + H - y, b_warp)
    weft = meets(x + y, b_weft) | meets(x - (H - y), b_weft)
    return warp, weft


def test_bias_zones_follow_the_geometric_definition(bias):
    # The held-end rule and the band definition differ only for a band edge passing within
    # half a segment of a corner; none does here (checked first: the clearance of each band
    # edge, where it meets y = 0 or y = H, from the nearest corner).
    x, y = bias.positions[bias.crossing_nodes[:, 0], :2].T
    b = [band_reach(0), band_reach(1)]
    for meet, reach in ((x - y, b[0]), (x + H - y, b[0]), (x + y, b[1]), (x - (H - y), b[1])):
        assert np.min(np.minimum(np.abs(meet + reach), np.abs(meet - W - reach))) > SPACING / N / 2
    warp, weft = clamp_reaches(x, y, *b)
    assert np.array_equal(bias.zone, warp.astype(int) + weft.astype(int))
    assert set(bias.zone) == {0, 1, 2}
    # Zone A in the middle diamond |x - W/2| + |y - H/2| < (H - W)/2 ... clipped by the long
    # sides; zone C in the clamp triangles on y = 0 and y = H (apex W/2 from the clamp),
    # widened by the bands, but for the two crossings at mid-height on the long sides: with
    # H = 2 W the yarns from the clamps' corners meet there, one gripped by each clamp.
    a, c = bias.zone == 0, bias.zone == 2
    assert np.all(np.abs(y[a] - H / 2) < (H - W) / 2 - np.abs(x[a] - W / 2))
    near = np.minimum(y, H - y)
    in_triangle = near <= np.minimum(x, W - x) + max(b)
    assert np.array_equal(np.flatnonzero(c & ~in_triangle),
                          np.flatnonzero(c & (np.abs(y - H / 2) < 1e-9)
                                         & (np.minimum(x, W - x) < min(b))))
    assert np.sum(c & ~in_triangle) == 2
    # The bands move zone C's apex on the centre line x = W/2 from the crossing at 23.4 mm to
    # the one at 30.7 mm (crossings 7.33 mm apart there, at H/2 - 7.33 k; the yarns through
    # the latter leave the long sides 0.7 mm from the clamp, within their 3.0 and 2.1 mm
    # bands): the apex lies within a band of W/2, as the continuum's does at W/2.
    centre = np.abs(x - W / 2) < 1e-9
    apex = np.max(near[c & centre])
    assert apex == pytest.approx(H / 2 - 4 * SPACING * math.sqrt(2.0), rel=1e-12)
    assert abs(apex - W / 2) < min(b)


def test_interior_crossings_have_a_crossing_on_each_side_along_both_yarns(bias):
    for (k, j), inner in zip(bias.crossing_lattice, bias.interior):
        on_warp = bias.crossing_lattice[bias.crossing_lattice[:, 0] == k, 1]
        on_weft = bias.crossing_lattice[bias.crossing_lattice[:, 1] == j, 0]
        expected = on_warp.min() < j < on_warp.max() and on_weft.min() < k < on_weft.max()
        assert inner == expected


# --------------------------------------------------------------------------
# Held nodes' motion.


def test_bias_moves_only_the_top_clamp_along_y(bias):
    d = 7e-3
    rest = bias.positions
    moved = held_positions(bias, rest, d) - rest[bias.held]
    top = rest[bias.held, 1] > H / 2
    # (y + d) - y rounds at eps H.
    np.testing.assert_allclose(moved[top], np.tile([0.0, d, 0.0], (top.sum(), 1)),
                               rtol=0, atol=EPS * H)
    assert top.sum() > 0 and (~top).sum() > 0
    np.testing.assert_array_equal(moved[~top], 0.0)
    np.testing.assert_array_equal(held_positions(bias, rest, 0.0), rest[bias.held])


def test_frame_bars_stay_rigid_and_the_corner_moves_along_the_diagonal(frame):
    L, rest = 0.06, frame.positions[frame.held]
    np.testing.assert_array_equal(held_positions(frame, frame.positions, 0.0)[:, 2], rest[:, 2])
    np.testing.assert_allclose(held_positions(frame, frame.positions, 0.0), rest,
                               rtol=0, atol=4 * EPS * L)
    bars = {"bottom": rest[:, 1] == 0, "top": rest[:, 1] == L,
            "left": rest[:, 0] == 0, "right": rest[:, 0] == L}
    assert all(b.sum() == 5 for b in bars.values())
    for d in (-0.01, 0.004, 0.012):
        moved = held_positions(frame, frame.positions, d)
        np.testing.assert_array_equal(moved[:, 2], rest[:, 2])
        # Pins on one bar keep their distances and stay on one line (a rigid bar).
        for bar in bars.values():
            p, p0 = moved[bar, :2], rest[bar, :2]
            np.testing.assert_allclose(np.linalg.norm(p - p[0], axis=1),
                                       np.linalg.norm(p0 - p0[0], axis=1), rtol=1e-12)
        # The bars through the fixed corner: the bottom bar's pins at x map to x u1, the
        # left bar's at y to y u2, |u1| = |u2| = 1; the hinges L u1, L u2 and the moved
        # corner L (u1 + u2), extrapolated from the top bar's pins.
        u1 = moved[bars["bottom"], :2] / rest[bars["bottom"], :1]
        u2 = moved[bars["left"], :2] / rest[bars["left"], 1:2]
        np.testing.assert_allclose(u1, np.tile(u1[0], (5, 1)), rtol=1e-12)
        np.testing.assert_allclose(u2, np.tile(u2[0], (5, 1)), rtol=1e-12)
        np.testing.assert_allclose([np.linalg.norm(u1[0]), np.linalg.norm(u2[0])], 1.0,
                                   rtol=1e-14)
        top, x_top = moved[bars["top"], :2], rest[bars["top"], 0]
        corner = top[0] + (L - x_top[0]) * u1[0]
        np.testing.assert_allclose(corner - [L, L], d * np.array([1.0, 1.0]) / math.sqrt(2),
                                   rtol=0, atol=16 * EPS * L)
        np.testing.assert_allclose(np.linalg.norm(corner - L * u2[0]), L, rtol=1e-13)


def test_held_velocity_is_the_derivative_of_held_positions(bias, frame):
    # Central difference with step h: truncation h^2/6 |x'''|. For the frame x = F(theta(d))
    # X with |X| <= sqrt(2) L, each d-derivative brings a factor about 1/(2 L sin theta):
    # |x'''| < 40/L^2 at these d (sin theta > 0.6); with h = 1e-6 m the truncation is below
    # 1e-12 x 40 / 6 / 3.6e-3 = 2e-9, the rounding below eps L / h = 1.3e-11. The bias map is
    # linear in d: only rounding.
    h = 1e-6
    for layout, d in ((bias, 3e-3), (frame, -0.008), (frame, 0.0), (frame, 0.01)):
        difference = (held_positions(layout, layout.positions, d + h)
                      - held_positions(layout, layout.positions, d - h)) / (2 * h)
        np.testing.assert_allclose(held_velocity(layout, layout.positions, d), difference,
                                   rtol=0, atol=3e-9)


# --------------------------------------------------------------------------
# Shear angles.


def test_nominal_angles_at_rest_and_at_the_limits(bias, frame):
    assert nominal_shear_angle(bias, 0.0) == pytest.approx(0.0, abs=4 * EPS)
    assert nominal_shear_angle("bias_extension", bias_limit(W, H), width=W, height=H) \
        == pytest.approx(math.pi / 2, abs=1e-7)     # acos near 1: sqrt(eps) sensitivity
    assert bias_limit(W, H) == pytest.approx((math.sqrt(2) - 1) * (H - W), rel=1e-15)
    assert nominal_shear_angle(frame, 0.0) == pytest.approx(0.0, abs=4 * EPS)
    # Frame: (2 - sqrt 2) L closes it to theta = 0, gamma = 90 degrees.
    assert nominal_shear_angle("picture_frame", (2 - math.sqrt(2)) * 0.06, side=0.06) \
        == pytest.approx(math.pi / 2, abs=1e-7)
    # Bias, eq. 13 at d = 0.2 L0: gamma = pi/2 - 2 acos(1.2 / sqrt 2) (= 0.456 rad); at
    # d = L0 the ratio (L0 + d)/(sqrt 2 L0) = sqrt 2 exceeds 1: refused (beyond the limit).
    expected = math.pi / 2 - 2 * math.acos(1.2 / math.sqrt(2))
    assert nominal_shear_angle(bias, 0.2 * (H - W)) == pytest.approx(expected, rel=1e-14)
    with pytest.raises(UserError, match="load.values"):
        nominal_shear_angle(bias, H - W)
    with pytest.raises(UserError, match="load.values"):
        nominal_shear_angle(frame, 0.036)      # beyond (2 - sqrt 2) L = 0.0351 m


def apply_frame_map(layout, d):
    moved = layout.positions.copy()
    theta = math.acos((math.sqrt(2) * 0.06 + d) / 0.12)
    moved[:, :2] = layout.positions[:, :2] @ frame_map(theta).T
    return moved


def test_homogeneous_trellis_shears_every_crossing_by_the_frame_angle(frame):
    # F(theta) maps every chord of a warp to u1 and of a weft to u2 (times its length), so
    # t_wa . t_we = cos(2 theta) = sin(gamma) at every crossing, chain ends included; the
    # rest angle is 0. Rounding: a few eps in the dot product, over cos(gamma) >= 0.5.
    np.testing.assert_array_equal(shear_angles(frame, frame.positions, frame.positions), 0.0)
    for d in (-0.01, 0.003, 0.01, 0.025):
        gamma = nominal_shear_angle(frame, d)
        got = shear_angles(frame, frame.positions, apply_frame_map(frame, d))
        np.testing.assert_allclose(got, gamma, rtol=0, atol=1e-12)
    assert nominal_shear_angle(frame, 0.025) > math.radians(34)


def rotate_about(points, centre, angle):
    c, s = math.cos(angle), math.sin(angle)
    return centre + (points - centre) @ np.array([[c, s], [-s, c]])


def test_bias_warps_and_wefts_turned_towards_the_pull_shear_by_their_angle(bias):
    # Warps at +45 degrees turned by +g/2 and wefts at 135 degrees by -g/2 meet at 90 - g
    # degrees: t_wa . t_we = sin g, so gamma = g (positive: the yarns turn towards the
    # pull). Turned about each crossing in turn; the chords do not depend on the centre.
    warp_nodes = np.repeat(bias.chain_family == 0, np.diff(bias.chain_start))
    g = 0.5
    for c, (warp_node, _) in enumerate(bias.crossing_nodes[::7]):
        centre = bias.positions[warp_node, :2]
        moved = bias.positions.copy()
        moved[warp_nodes, :2] = rotate_about(bias.positions[warp_nodes, :2], centre, g / 2)
        moved[~warp_nodes, :2] = rotate_about(bias.positions[~warp_nodes, :2], centre, -g / 2)
        got = shear_angles(bias, bias.positions, moved)
        np.testing.assert_allclose(got, g, rtol=0, atol=1e-12)


# --------------------------------------------------------------------------
# Lateral contact stencils.


def lateral_distances(layout, positions):
    before, after, a, b = positions[layout.lateral.T, :2]
    c = after - before
    cross = c[:, 0] * (b - a)[:, 1] - c[:, 1] * (b - a)[:, 0]
    return layout.lateral_sign * cross / np.linalg.norm(c, axis=1)


def test_lateral_stencils_join_neighbouring_yarns_across_a_shared_yarn(bias, frame):
    for layout in (bias, frame):
        chain = np.searchsorted(layout.chain_start, layout.lateral, side="right") - 1
        family, index = layout.chain_family[chain], layout.chain_index[chain]
        assert np.all(family[:, [0, 1, 2]] == family[:, [3]])
        assert np.all(index[:, [0, 1]] == index[:, [2]])
        assert np.all(index[:, 3] == index[:, 2] + 1)
        # A and B are crossing nodes on the same yarn of the other family.
        lattice = {}
        for (wa, we), kj in zip(layout.crossing_nodes, layout.crossing_lattice):
            lattice[wa], lattice[we] = tuple(kj), tuple(kj)
        for f, a, b in zip(family[:, 0], layout.lateral[:, 2], layout.lateral[:, 3]):
            assert lattice[a][1 - f] == lattice[b][1 - f]
    # Every neighbouring pair on every shared crossing yarn: the frame's 40 by hand above;
    # the bias count from the crossing table.
    kept = {tuple(c) for c in bias.crossing_lattice}
    expected = sum((k + 1, j) in kept for k, j in kept) + sum((k, j + 1) in kept for k, j in kept)
    assert len(bias.lateral) == expected


def test_lateral_distance_is_the_spacing_and_closes_as_cos_gamma(bias_unequal, frame):
    # At rest B lies one spacing of its family from A's chord line; the frame map turns the
    # chord to u1 (warps) and B - A = spacing u2, so the distance is spacing sin(2 theta) =
    # spacing cos(gamma) (the locking law of docs/model.md section 11).
    for layout, spacings in ((bias_unequal, (5.18e-3, 6.1e-3)), (frame, (0.01, 0.012))):
        family = layout.chain_family[np.searchsorted(layout.chain_start, layout.lateral[:, 2],
                                                     side="right") - 1]
        spacing = np.asarray(spacings)[family]
        np.testing.assert_allclose(lateral_distances(layout, layout.positions), spacing,
                                   rtol=1e-12)
    for d in (-0.01, 0.01, 0.02):
        spacing = np.asarray((0.01, 0.012))[frame.chain_family[np.searchsorted(
            frame.chain_start, frame.lateral[:, 2], side="right") - 1]]
        gamma = nominal_shear_angle(frame, d)
        np.testing.assert_allclose(lateral_distances(frame, apply_frame_map(frame, d)),
                                   spacing * math.cos(gamma), rtol=1e-12)


# --------------------------------------------------------------------------
# Bad input.


@pytest.mark.parametrize("args, key", [
    ((0.06, 0.11), "specimen.height"),
    ((0.0, 0.12), "specimen.width"),
    ((-0.06, 0.12), "specimen.width"),
    ((0.06, 0.0), "specimen.height"),
    ((0.01, 0.12), "specimen.width"),     # one crossing across the centre row
])
def test_bad_bias_specimens_are_refused_in_one_line(args, key):
    with pytest.raises(UserError, match=key) as error:
        bias_extension(*args, SPACING, SPACING, A_WARP, A_WEFT, N, YARN_WIDTHS)
    assert "\n" not in str(error.value)


@pytest.mark.parametrize("widths, key", [((0.0, 3e-3), "warp.width"),
                                          ((4.2e-3, -1e-3), "weft.width")])
def test_a_bias_yarn_width_not_positive_is_refused_in_one_line(widths, key):
    with pytest.raises(UserError, match=key) as error:
        bias_extension(W, H, SPACING, SPACING, A_WARP, A_WEFT, N, widths)
    assert "\n" not in str(error.value)


@pytest.mark.parametrize("side, spacing, key", [
    (0.0, 0.01, "specimen.side"),
    (0.02, 0.01, "specimen.side"),        # only k = 0 is clear of the bars
    (0.06, -0.01, "warp.spacing"),
])
def test_bad_frames_are_refused_in_one_line(side, spacing, key):
    with pytest.raises(UserError, match=key) as error:
        picture_frame(side, spacing, 0.01, A_WARP, A_WEFT, N)
    assert "\n" not in str(error.value)


def test_a_bad_segment_count_is_refused():
    for bad in (0, 2.5, True):
        with pytest.raises(UserError, match="specimen.segments_per_spacing"):
            picture_frame(0.06, 0.01, 0.01, A_WARP, A_WEFT, bad)


@pytest.mark.parametrize("name", ["frame", "bias"])
def test_a_clamp_grips_the_end_piece_up_to_the_first_crossing(name, request):
    """Held nodes are the held ends and, on their chains, every node between such an end
    and the chain's nearest crossing node (that one free): the clamp's strip of fabric."""
    layout = request.getfixturevalue(name)
    crossing = np.zeros(layout.held.size, bool)
    crossing[layout.crossing_nodes.ravel()] = True
    expected = np.zeros_like(layout.held)
    for nodes in chains(layout):
        on = nodes[crossing[nodes]]
        if layout.held[nodes[0]]:
            expected[nodes[nodes < on[0]]] = True
        if layout.held[nodes[-1]]:
            expected[nodes[nodes > on[-1]]] = True
    assert np.array_equal(layout.held, expected)
    assert not layout.held[crossing].any()
    assert (layout.held & ~np.isin(np.arange(layout.held.size), chain_ends(layout))).any()
