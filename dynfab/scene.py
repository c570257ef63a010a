"""Scene files: TOML in SI units, parsed once at the boundary into frozen dataclasses.

The keys are a contract (README, docs/scene.md): scripts and users rely on
them. Every field documents its unit. Validation happens here and only here;
a user's mistake raises `UserError` with one line naming the key, the value
and what is allowed.

Each key is a dataclass field declared once, with `_key(...)`: its meaning, unit,
rule (or choices), default, whether a [sweep] may vary it, whether it is a run
option (a `dynfab run` flag) and which kind of scene takes it (its model, spatial
kinematics, a layout that a [specimen] sets). The parser, the validation messages, the run
options (`dynfab.options`), the command line's flags and docs/scene.md
(`markdown_table`, `python -m dynfab.scene --markdown`) are all read from there; which
kind of scene refuses which keys and tables is declared once too (`_KEY_REFUSALS`,
`_TABLE_REFUSALS`), and one check (`_refuse`) applies it.

Public: `load_scene`, `parse_scene_text`, `scene_from_tables`, `validate_scene` (for a Scene built
in Python), `check_dynamic_options` (for solver options given apart from a
scene), `with_key`, `expand_sweep`, `yarn_count`, `markdown_table`, and the specimen's
constants `PAPER_FRICTION`, `TORSION_RADIUS_PER_WIDTH`. Choices made here:

- a scene without crossings (a plain rod) refuses a [weft], [contact] or [friction] table
  and a non-zero geometry.amplitude, rather than ignoring them;
- [dynamic] keys that the chosen mode or damping would ignore (duration and
  output_interval outside "transient", damping_coefficient without viscous
  damping) are refused too;
- integer keys refuse floats, even 16.0; real keys accept integers;
- load.max must be non-zero (a path at zero load is `values = [0.0]`);
- a [sweep] key may be quoted ("warp.EA" = [...]) or bare (warp.EA = [...]),
  and may be left out of its table, which then takes the first entry;
  weft.count is not sweepable (an integer; sweeps hold reals);
- a [specimen] (the spatial fabric's shear test, docs/model.md section 11) sets the layout:
  the layout keys (geometry.length, segments, crossings, amplitude, weft.length, count,
  segments) are refused with it and required without it; spatial kinematics and a
  [specimen] go together, and a planar scene refuses the spatial keys of [crossing] and
  the families. A specimen without [friction] runs the paper's Gralen law (`PAPER_FRICTION`, the
  `Specimen` decision), resolved by `validate_scene` with its other defaults;
- the spatial keys are not sweepable: they are the fabric's, which takes no [sweep] (a
  fabric's fit varies its real keys whether sweepable or not, `dynfab.fitting.models`).
"""

from __future__ import annotations

import datetime
import difflib
import functools
import json
import math
import numbers
import tomllib
import weakref
from dataclasses import MISSING, dataclass, field, fields, replace
from pathlib import Path

from dynfab.errors import UserError


# --------------------------------------------------------------------------
# The schema: each scene key is a dataclass field, described once by its metadata.


@dataclass(frozen=True)
class _Key:
    """How one scene key is read, checked and documented."""

    kind: str = ""
    """"float", "int", "str" or "floats" (a non-empty list of numbers); from the field's type."""
    unit: str = ""
    rule: str = ""
    """"", "positive", "nonnegative" or "nonzero"."""
    choices: tuple[str, ...] = ()
    doc: str = ""
    """What the key is, for the documentation table and the command line's help."""
    sweepable: bool = False
    """A [sweep] may vary it: real-valued, changing no array shape (docs/model.md section 1)."""
    option: bool = False
    """A run option ([static], [dynamic]): a `dynfab run` flag and a `dynfab.run` keyword."""
    default_from: str = ""
    """When left out of the TOML: the value of this other key."""
    model: str = ""
    """"fabric": a key of the woven fabric only; "yarn": of the one-yarn model only (docs/model.md
    section 10); "": both. A scene of the other model refuses it."""
    default_doc: str = ""
    """The default as docs/scene.md writes it (Markdown) where it depends on other keys; the
    field's default is then None, resolved by `validate_scene`."""
    layout: bool = False
    """A key of the layout of a patch (its lengths, yarn counts, segments, the warp's crimp): a
    [specimen] sets the layout and refuses it; without one, a key of the one-yarn model and
    the planar fabric is required (weft.segments: in a fabric)."""
    spatial: bool = False
    """A key of the spatial fabric only (geometry.kinematics = "spatial", docs/model.md
    section 11); a planar scene refuses it."""
    hint: str = "remove it"
    """How the refusal of the key ends where a fabric, a planar fabric or a [specimen] refuses
    it (`_KEY_REFUSALS`): what to do, why it means nothing there, or where that scene's value
    lives instead (a one-yarn scene's refusal of the fabric's keys says one thing of all)."""


_POS, _NONNEG = "positive", "nonnegative"
CELL_PLANES = "cell"
"""geometry.planes of a periodic cell: its planes move with the cell (docs/model.md section 10)."""
PLANES = ("fixed", "affine", CELL_PLANES)


def _key(doc: str, unit: str = "", rule: str = "", *, choices: tuple[str, ...] = (),
         sweepable: bool = False, option: bool = False, default_from: str = "",
         model: str = "", default=MISSING, default_doc: str = "", layout: bool = False,
         spatial: bool = False, hint: str = "remove it"):
    """A dataclass field that is a scene key: its description, unit, rule and roles.

    The key's kind (real, integer, string, list) is its field's type; a field
    without `default` is required (unless `default_from` fills it at parse time).
    """
    spec = _Key(unit=unit, rule=rule, choices=choices, doc=doc, sweepable=sweepable,
                option=option, default_from=default_from, model=model,
                default_doc=default_doc, layout=layout, spatial=spatial, hint=hint)
    return field(default=default, metadata={"scene_key": spec})


_SPATIAL = 'geometry.kinematics = "spatial"'


@dataclass(frozen=True, kw_only=True)
class Geometry:
    """The warp yarn's geometry (docs/model.md section 1)."""

    length: float | None = _key("L, projected warp length", "m", _POS, default=None, layout=True)
    segments: int | None = _key("N, segments per warp yarn; a multiple of 2 x crossings",
                                rule=_POS, default=None, layout=True)
    crossings: int | None = _key("N_we, weft crossings per warp yarn; 0 is a plain straight rod",
                                 rule=_NONNEG, default=None, layout=True)
    amplitude: float | None = _key("A_wa, as-woven warp crimp amplitude; 0 is a straight yarn",
                                   "m", _NONNEG, sweepable=True, default=None, layout=True,
                                   hint="remove it (a specimen's warp crimp is warp.amplitude)")
    reference: str = _key("stress-free state (docs/model.md section 3)",
                          choices=("as_woven", "prestressed"), default="as_woven")
    yarns: int = _key("adjacent warp yarns simulated, yarn k with phase s_k = (-1)^(k-1)",
                      rule=_POS, default=1, model="yarn",
                      hint="the fabric simulates weft.count warps and geometry.crossings "
                           "wefts; remove it")
    model: str = _key("one warp yarn against weft springs (docs/model.md sections 1-9), or the woven "
                      "fabric, warps and wefts alike as chains (docs/model.md section 10)",
                      choices=("yarn", "fabric"), default="yarn")
    boundary: str = _key("a finite patch, or a periodic unit cell (docs/model.md section 10)",
                         choices=("clamped", "periodic"), default="clamped", model="fabric")
    planes: str | None = _key("the yarns' planes X_j, Y_k: as woven, moving with the patch's "
                              "mean stretch, or with the periodic cell (a periodic cell's only "
                              "planes; docs/model.md section 10)",
                              choices=PLANES, default=None, model="fabric",
                              default_doc=f'`"fixed"`; on a periodic cell `"{CELL_PLANES}"`; '
                                          'none with spatial kinematics (which refuses it)')
    kinematics: str = _key("every yarn in its vertical plane (docs/model.md section 10), or nodes "
                           "free in x, y and z, sheared in plane by a [specimen] test "
                           "(docs/model.md section 11), which spatial kinematics requires",
                           choices=("planar", "spatial"), default="planar", model="fabric")


@dataclass(frozen=True, kw_only=True)
class Specimen:
    """An in-plane shear test of the spatial fabric (docs/model.md section 11).

    A bias extension or a picture frame (Cao et al., Composites A 39 (2008) 1037-1053).

    It sets the layout: yarns at whole spacings (warp.spacing, weft.spacing) from a crossing
    at the specimen's centre, so geometry.length, segments, crossings, amplitude and
    weft.length, count, segments are refused. It is loaded by its clamp (frame corner)
    displacement, load.values, alone.

    Decision: a specimen without a [friction] table takes the paper's Gralen law
    (`PAPER_FRICTION`, docs/model.md section 7), not none: without friction a bias specimen
    slides apart at no cost, so the table's absence must not silently mean frictionless;
    friction.alpha = friction.beta = 0 written out switches it off.
    """

    test: str = _key("the test: a W x H bias-extension strip, yarns at +-45 degrees to its long "
                     "side, clamped at its short sides; or a L x L picture frame, yarns along "
                     "the bars, every end pinned to a bar",
                     choices=("bias_extension", "picture_frame"), model="fabric", spatial=True)
    width: float | None = _key("bias extension: W, the clamped short side; required there", "m",
                               _POS, default=None, model="fabric", spatial=True)
    height: float | None = _key("bias extension: H >= 2W, the free length between the clamps; "
                                "required there", "m", _POS, default=None, model="fabric",
                                spatial=True)
    side: float | None = _key("picture frame: L, the frame's side, pin to pin; required there",
                              "m", _POS, default=None, model="fabric", spatial=True)
    fabric_side: float | None = _key("picture frame: L_fabric <= L, the sheared fabric's side in "
                                     "the normalised shear force F_s L / L_fabric^2 (Cao et al. "
                                     "2008, eq. 10)", "m", _POS, default=None, model="fabric",
                                     spatial=True, default_doc="`specimen.side`")
    segments_per_spacing: int = _key("segments of each yarn between consecutive crossings",
                                     rule=_POS, default=4, model="fabric", spatial=True)


def _lateral_keys(family: str, plural: str) -> dict:
    """The spatial fabric's keys of one yarn family (docs/model.md section 11), as fields."""
    spatial = {"default": None, "model": "fabric", "spatial": True}
    return {
        "spacing": _key(f"p, centre-to-centre distance of neighbouring {plural}; required with "
                        "[specimen]", "m", _POS, **spatial),
        "width": _key(f"w, {family} yarn width, below {family}.spacing: neighbouring {plural} "
                      "meet (lateral contact, locking) closer than it; required with [specimen]",
                      "m", _POS, **spatial),
        "EI_lateral": _key("in-plane (lateral) bending stiffness", "N m^2", _POS,
                           default_doc=f"`{family}.EI`", **spatial),
        "lateral_stiffness": _key(f"k, stiffness of the lateral contact of neighbouring "
                                  f"{plural}, per crossing: the contact's whole law without "
                                  f"`{family}.fibre_modulus`, with it the yarns' core past "
                                  "their fibres' packing (docs/model.md 11.5)", "N/m", _POS,
                                  default_doc="`contact.core_stiffness`; without it the "
                                              "fabric's 1e5 N/m", **spatial),
        "fibre_modulus": _key(f"E_f, Young's modulus of the {family}'s fibres: with it "
                              f"neighbouring {plural} compact sideways by Gutowski's law "
                              "(docs/model.md 11.5), which also needs fibre_volume_fraction, "
                              "packing_limit and fibre_waviness; without it the lateral "
                              "contact is the linear lateral_stiffness", "Pa", _POS, **spatial),
        "fibre_volume_fraction": _key(f"V0, fibre volume fraction of the {family} yarn as "
                                      "woven (its fibres' cross-section over the yarn's, "
                                      "below packing_limit)", "-", _POS, **spatial),
        "packing_limit": _key("V_a, the largest fibre volume fraction the yarn's fibres can "
                              "pack to (square packing pi/4 = 0.785, hexagonal 0.907)", "-",
                              _POS, **spatial),
        "fibre_waviness": _key("beta, the fibres' span between contacts over their waviness "
                               "amplitude in the yarn (Gutowski's; the law's stiffness "
                               "3 pi E_f / beta^4)", "-", _POS, **spatial),
    }


_WARP_LATERAL, _WEFT_LATERAL = _lateral_keys("warp", "warps"), _lateral_keys("weft", "wefts")


@dataclass(frozen=True, kw_only=True)
class Warp:
    """Warp yarn material (docs/model.md sections 2-3)."""

    EA: float = _key("extensional stiffness", "N", _POS, sweepable=True)
    EI: float = _key("bending stiffness", "N m^2", _POS, sweepable=True)
    kawabata_C: float = _key("Kawabata C_wa, limit compression", "m", _POS, sweepable=True)
    kawabata_K: float = _key("Kawabata K_wa, compliance parameter", "m/N", _POS, sweepable=True)
    linear_density: float = _key("rho_l, mass per unit length", "kg/m", _POS, sweepable=True,
                                 default=3e-5)
    amplitude: float | None = _key("A_wa, as-woven warp crimp half-height of a [specimen] (a "
                                   "planar fabric's is geometry.amplitude); required there", "m",
                                   _NONNEG, default=None, model="fabric", spatial=True,
                                   hint="a planar fabric's warp crimp is geometry.amplitude")
    spacing: float | None = _WARP_LATERAL["spacing"]
    width: float | None = _WARP_LATERAL["width"]
    EI_lateral: float | None = _WARP_LATERAL["EI_lateral"]
    lateral_stiffness: float | None = _WARP_LATERAL["lateral_stiffness"]
    fibre_modulus: float | None = _WARP_LATERAL["fibre_modulus"]
    fibre_volume_fraction: float | None = _WARP_LATERAL["fibre_volume_fraction"]
    packing_limit: float | None = _WARP_LATERAL["packing_limit"]
    fibre_waviness: float | None = _WARP_LATERAL["fibre_waviness"]


@dataclass(frozen=True, kw_only=True)
class Weft:
    """The weft at a crossing: a beam spring in series with Kawabata (docs/model.md section 3)."""

    EI: float = _key("weft bending stiffness", "N m^2", _POS, sweepable=True)
    length: float | None = _key("L_we, projected weft length", "m", _POS, sweepable=True,
                                default=None, default_from="geometry.length", layout=True)
    count: int | None = _key("N_wa, warp yarns crossing one weft", rule=_POS, default=None,
                             default_from="geometry.crossings", layout=True)
    amplitude: float = _key("A_we, weft crimp amplitude", "m", _NONNEG, sweepable=True)
    kawabata_C: float = _key("Kawabata C_we", "m", _POS, sweepable=True)
    kawabata_K: float = _key("Kawabata K_we", "m/N", _POS, sweepable=True)
    tension: float = _key("P_we, weft tension; negative is compression, above -pi^2 EI/L_we^2",
                          "N", sweepable=True, default=0.0, model="yarn",
                          hint="the wefts are chains, loaded by load.weft_values; remove it")
    EA: float | None = _key("weft extensional stiffness; required in a fabric", "N", _POS,
                            default=None, model="fabric")
    linear_density: float | None = _key("weft rho_l, mass per unit length; none: 3e-5", "kg/m",
                                        _POS, default=None, model="fabric")
    segments: int | None = _key("M, segments per weft yarn, a multiple of 2 x weft.count; "
                                "required in a fabric", rule=_POS, default=None, model="fabric",
                                layout=True)
    spacing: float | None = _WEFT_LATERAL["spacing"]
    width: float | None = _WEFT_LATERAL["width"]
    EI_lateral: float | None = _WEFT_LATERAL["EI_lateral"]
    lateral_stiffness: float | None = _WEFT_LATERAL["lateral_stiffness"]
    fibre_modulus: float | None = _WEFT_LATERAL["fibre_modulus"]
    fibre_volume_fraction: float | None = _WEFT_LATERAL["fibre_volume_fraction"]
    packing_limit: float | None = _WEFT_LATERAL["packing_limit"]
    fibre_waviness: float | None = _WEFT_LATERAL["fibre_waviness"]


DEFAULT_CORE_STIFFNESS = 1e5
"""k_c [N/m] of a fabric scene without contact.core_stiffness (docs/model.md section 10)."""
TORSION_RADIUS_PER_WIDTH = (math.sqrt(2.0) + math.asinh(1.0)) / 6.0
"""rho / w = 0.3826: the mean distance to the centre of a w x w square, (sqrt(2) +
ln(1 + sqrt(2))) / 6 w, the default torsion radius of a crossing of uniform pressure
(docs/model.md section 11)."""


@dataclass(frozen=True, kw_only=True)
class Crossing:
    """The fabric's crossing laws (docs/model.md sections 10 and 11).

    The contact force woven in (any fabric); the rotation's elastic spring and its lever in
    friction (the spatial fabric).
    """

    preload: float = _key("R_p, contact force woven in at every crossing: the yarns' rest shapes "
                          "hold it in the as-woven fabric at zero load, with no tension "
                          "(docs/model.md section 10, the woven-in contact); a [specimen] "
                          "requires it > 0, without it every friction limit is zero", "N",
                          _NONNEG, default=0.0, model="fabric")
    shear_stiffness: float | None = _key(
        "elastic spring on a crossing's rotation (the in-plane angle between warp and weft); "
        "with it 0 and the rotation sliding, only the lateral bending (EI_lateral) resists the "
        "shear: a soft, ill-conditioned mode", "N m/rad", _NONNEG, default=None, model="fabric",
        spatial=True, default_doc="`0`")
    torsion_radius: float | None = _key(
        "rho, the rotation's lever in the friction slip |(s_x, s_y, rho phi)|: the rotation "
        "sticks with k_t rho^2 and slides at the moment rho F_T", "m", _POS, default=None,
        model="fabric", spatial=True,
        default_doc="0.3826 x the smaller of `warp.width` and `weft.width` (the mean distance "
                    "to the centre of a w x w square)")
    motion: str = _key(
        "how a crossing moves along its yarns: \"fixed\", a fixed pair of nodes, one on each "
        "yarn, and a step whose slip passes half a segment stops (docs/model.md 11.6); "
        "\"sliding\", its contact point stays where the yarns cross while their material "
        "slides through it, and a yarn end that passes its last crossing leaves it "
        "(docs/model.md 11.13; every fabric model, on the static solver or the dynamic "
        "one's explicit relaxation)",
        choices=("fixed", "sliding"), default="fixed", model="fabric")


@dataclass(frozen=True, kw_only=True)
class Friction:
    """Gralen friction with stick-slip regularisation (docs/model.md section 4)."""

    alpha: float = _key("Gralen alpha", "-", _NONNEG, sweepable=True)
    beta: float = _key("Gralen beta", "N/m^2", _NONNEG, sweepable=True)
    contact_length: float = _key("ell, effective contact length", "m", _NONNEG, sweepable=True)
    fiber_radius: float = _key("r_f, fibre radius", "m", _NONNEG, sweepable=True)
    stick_stiffness: float | None = _key("k_t; none: EA / (L/N) of each yarn", "N/m", _POS,
                                         sweepable=True, default=None)
    onset_force: float = _key("R_0; the limit's constant term sets in as 1 - exp(-R/R_0); 0 is "
                              "the literal jump law (docs/model.md section 4)", "N", _NONNEG,
                              sweepable=True, default=1e-5)


PAPER_FRICTION = Friction(alpha=0.2, beta=1e3, contact_length=2e-3, fiber_radius=1e-3)
"""The paper's Gralen law (docs/model.md section 7, Fig. 5's friction-on curve): what a
[specimen] without a [friction] table runs (the `Specimen` decision)."""


@dataclass(frozen=True, kw_only=True)
class Contact:
    """Options of the crossing contact law (docs/model.md section 3)."""

    core_stiffness: float | None = _key(
        "k_c, the yarns' core stiffness in series with the weft spring and the Kawabata "
        "compressions; none: no such spring (a fabric: 1e5 N/m, docs/model.md section 10)", "N/m",
        _POS, sweepable=True, default=None)


@dataclass(frozen=True, kw_only=True)
class Gravity:
    """Gravity along -z, acting on the physical masses (docs/model.md section 2)."""

    g: float = _key("gravitational acceleration", "m/s^2", sweepable=True, default=9.81)


@dataclass(frozen=True, kw_only=True)
class Load:
    """The load path (docs/model.md section 4: exactly these values, no zero step)."""

    control: str = _key('what the values are: P per warp yarn [N] ("force") or the end '
                        'displacement [m] ("displacement")', choices=("force", "displacement"),
                        default="force")
    values: tuple[float, ...] = _key("the load steps, in order", "N or m")
    weft_values: tuple[float, ...] | None = _key(
        "the load per weft yarn at each step, as many as values; none: zeros", "N or m",
        default=None, model="fabric")
    warp_factors: tuple[float, ...] | None = _key(
        "a factor per warp yarn (weft.count of them) on its load; none: 1 each", "-",
        default=None, model="fabric")
    weft_factors: tuple[float, ...] | None = _key(
        "a factor per weft yarn (geometry.crossings of them) on its load; none: 1 each", "-",
        default=None, model="fabric")


@dataclass(frozen=True, kw_only=True)
class Pullout:
    """One warp pulled out of a clamped fabric patch (docs/model.md section 10)."""

    warp: int = _key("the warp pulled (1..weft.count): its first node free, its last node "
                     "displaced by load.values; every other warp held at both ends", rule=_POS,
                     model="fabric")


_ACCURACY = "largest accepted position error bound of a step, relative to its largest displacement"


@dataclass(frozen=True, kw_only=True)
class Static:
    """Options of the static Newton reference solver (docs/model.md section 6)."""

    tolerance: float = _key("force residual to reach (or the rounding floor, where higher)", "N",
                            _POS, option=True, default=1e-11)
    max_iterations: int = _key("Newton iterations per load step before the step is declared "
                               "failed", rule=_POS, option=True, default=200)
    accuracy: float = _key(_ACCURACY, "-", _POS, option=True, default=0.1)


@dataclass(frozen=True, kw_only=True)
class Dynamic:
    """Options of the dynamic (Warp) solver (docs/model.md section 5)."""

    mode: str = _key("relax each load step, or integrate in time",
                     choices=("quasi_static", "transient"), option=True, default="quasi_static")
    method: str = _key("symplectic Euler, or linearly implicit Euler",
                       choices=("explicit", "semi_implicit"), option=True, default="explicit")
    damping: str | None = _key(
        "none: kinetic (quasi-static), viscous (transient); semi_implicit takes no kinetic "
        "damping (its steps are undone instead) and no FIRE; it uses a viscous c only when "
        "one is given", choices=("kinetic", "viscous", "fire"), option=True, default=None)
    damping_coefficient: float | None = _key("viscous c; none: adaptive (quasi-static) or 0 "
                                             "(transient)", "1/s", _NONNEG, option=True,
                                             default=None)
    masses: str | None = _key("none: fictitious (quasi-static), physical (transient)",
                              choices=("fictitious", "physical"), option=True, default=None)
    dt: float | None = _key("time step; none: 1 s with fictitious masses (Gershgorin chooses the "
                            "masses), safety x the Gershgorin stability bound with physical "
                            "masses", "s", _POS, option=True, default=None)
    safety: float = _key("fraction of the predicted stable time step used", "-", _POS,
                         option=True, default=0.9)
    tolerance: float | None = _key("force residual; none: 1e-8 (float64), 1e-4 (float32)", "N",
                                   _POS, option=True, default=None)
    max_steps: int = _key("time steps allowed per load step", rule=_POS, option=True,
                          default=1_000_000)
    precision: str = _key("floating-point precision of the kernels",
                          choices=("float64", "float32"), option=True, default="float64")
    accuracy: float = _key(_ACCURACY, "-", _POS, option=True, default=0.1)
    duration: float | None = _key("transient: simulated time", "s", _POS, default=None)
    output_interval: float | None = _key("transient: time between frames", "s", _POS,
                                         default=None)

    def damping_used(self) -> str:
        """The damping the solver runs: `damping`, else viscous (transient) or kinetic."""
        return self.damping or ("viscous" if self.mode == "transient" else "kinetic")

    def masses_used(self) -> str:
        """The masses the solver uses: `masses`, else physical (transient) or fictitious."""
        return self.masses or ("physical" if self.mode == "transient" else "fictitious")


@dataclass(frozen=True, kw_only=True)
class Scene:
    """A whole scene: what is simulated, how it is loaded, and solver options."""

    title: str = ""
    geometry: Geometry
    specimen: Specimen | None = None
    """A spatial fabric's shear test, only when given (then geometry.kinematics = "spatial")."""
    warp: Warp
    weft: Weft | None = None
    """Absent exactly when geometry.crossings == 0 (a [specimen] requires it)."""
    crossing: Crossing | None = None
    """The spatial fabric's crossing laws, only when given."""
    contact: Contact | None = None
    """Only when given; a plain rod refuses it."""
    friction: Friction | None = None
    gravity: Gravity | None = None
    load: Load
    pullout: Pullout | None = None
    """A fabric's pull-out, only when given."""
    sweep: tuple[tuple[str, tuple[float, ...]], ...] = ()
    """Zipped lists ("table.key", values), one batched yarn per entry."""
    static: Static = field(default_factory=Static)
    dynamic: Dynamic = field(default_factory=Dynamic)
    text: str = ""
    """The TOML source, stored in every result file."""


# --------------------------------------------------------------------------
# Tables derived from the fields' metadata.

_KINDS = {"float": "float", "float | None": "float", "int": "int", "str": "str",
          "str | None": "str", "tuple[float, ...]": "floats", "int | None": "int",
          "tuple[float, ...] | None": "floats"}
"""A field's type (as written) -> the kind of its key."""


def _keys_of(cls: type) -> dict[str, _Key]:
    """Field name -> key spec of one table's dataclass, the kind taken from the field's type."""
    return {f.name: replace(f.metadata["scene_key"], kind=_KINDS[f.type]) for f in fields(cls)}


_TABLES = {"geometry": Geometry, "specimen": Specimen, "warp": Warp, "weft": Weft,
           "crossing": Crossing, "contact": Contact, "friction": Friction, "gravity": Gravity,
           "load": Load, "pullout": Pullout, "static": Static, "dynamic": Dynamic}
_SCHEMA: dict[str, tuple[type, dict[str, _Key]]] = {
    name: (cls, _keys_of(cls)) for name, cls in _TABLES.items()}
"""Table -> (dataclass, keys). The TOML key set is a contract: never rename."""
_DEFAULTS = {name: {f.name: f.default for f in fields(cls)} for name, (cls, _) in _SCHEMA.items()}
"""Table -> {key: its field's default (MISSING: required)}."""

_TITLE = _Key("str", doc="free text, stored with the results")

MAX_LOAD_STEPS = 10_000_000
"""Most load steps a `max`/`steps` path may have (the list of values is built at parse)."""

_LOAD_PATH = {
    "max": _Key("float", "N or m", "nonzero", doc="the last load step (instead of values)"),
    "steps": _Key("int", rule=_POS, doc="load steps: values = max k / steps, k = 1..steps"),
}
"""The other way to write a load path: values = max k / steps, k = 1..steps."""

_TOP_KEYS = ("title", *_SCHEMA, "sweep")
_REQUIRED_TABLES = ("geometry", "warp", "load")
_FIELD_KEYS = tuple(f"{t}.{k}" for t, (_, keys) in _SCHEMA.items() for k in keys)
_ALL_KEYS = _FIELD_KEYS + tuple(f"load.{k}" for k in _LOAD_PATH)
_SWEEPABLE = tuple(f"{t}.{k}" for t, (_, keys) in _SCHEMA.items()
                   for k, spec in keys.items() if spec.sweepable)
"""Keys a [sweep] may vary: real-valued, changing no array shape (docs/model.md section 1)."""

RUN_OPTIONS = {solver: {k: spec for k, spec in _SCHEMA[solver][1].items() if spec.option}
               for solver in ("static", "dynamic")}
"""Solver -> its table's keys that are run options (`dynfab.options`, `dynfab run` flags)."""

# The kinds of scene (`_kind`), and the tables and keys each refuses.

_FABRIC, _YARN = 'geometry.model = "fabric"', 'geometry.model = "yarn"'

_KEY_REFUSALS = {
    "yarn": ("model", "fabric", '{key} = {value}: a key of the woven fabric (docs/model.md '
             'section 10), but geometry.model = "yarn": set geometry.model = "fabric" or '
             'remove it'),
    "fabric": ("model", "yarn", '{key} = {value}: means nothing in a fabric (geometry.model = '
               '"fabric", docs/model.md section 10): {hint}'),
    "planar": ("spatial", True, '{key} = {value}: a key of the spatial fabric (geometry.'
               'kinematics = "spatial", docs/model.md section 11), but geometry.kinematics = '
               '"planar": {hint}'),
    "specimen": ("layout", True, "[specimen] sets the layout: {key} is not used; {hint}"),
}
"""Facet of a scene's kind -> (`_Key` field, value, refusal): the declaration of the keys it
refuses, and what it says of one (its value shown, `_show`; its hint, `_Key.hint`): a
one-yarn scene refuses the fabric's keys, a fabric the one-yarn model's (docs/model.md section
10), a planar fabric the spatial keys (section 11), a [specimen] the layout keys (it sets the
layout)."""

_TABLE_REFUSALS = {
    "pullout": {"yarn": 'a pull-out is a fabric scene (docs/model.md section 10); set '
                        'geometry.model = "fabric" or remove [pullout]'},
    "sweep": {"fabric": "a patch is one coupled group, not a batch of independent yarns "
                        "(docs/model.md section 10); vary it in a study (dynfab study, a [vary] "
                        "table: runs/study_example.toml)"},
    "specimen": {"yarn": "a table of the spatial fabric (docs/model.md section 11); set "
                         f'geometry.model = "fabric" and {_SPATIAL}, or remove [specimen]'},
    "crossing": {"yarn": "a table of the woven fabric (docs/model.md section 10); set "
                         'geometry.model = "fabric", or remove [crossing]'},
    **{name: {"rod": f"a plain rod has no crossings; remove the [{name}] table or set "
                     "crossings > 0"} for name in ("weft", "contact", "friction")},
}
"""Table -> {facet of a scene's kind that refuses it: why}, refused as `[table] given but
<_GIVEN_BUT[facet]>: why`; a scene built in Python is checked in this order."""
_GIVEN_BUT = {"yarn": _YARN, "fabric": _FABRIC, "rod": "geometry.crossings = 0"}


# --------------------------------------------------------------------------
# Public functions.


def load_scene(path) -> Scene:
    """Read and validate the TOML scene file at `path` (UserError if it cannot)."""
    path = Path(path)
    return parse_scene_text(read_text_file(path, "scene file"), source=str(path))


def read_text_file(path: Path, what: str) -> str:
    """The UTF-8 text of the file at `path`, a `what` ("scene file", "study file") in the
    UserError that says why it cannot be read."""
    try:
        return path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise UserError(f"{what} '{path}' not found") from None
    except UnicodeDecodeError:
        raise UserError(f"{what} '{path}' is not UTF-8 text") from None
    except OSError as exc:
        raise UserError(f"cannot read {what} '{path}': {exc.strerror}") from None


def parse_scene_text(text: str, source: str = "<string>") -> Scene:
    """Parse and validate TOML scene text; `source` names it in a syntax error."""
    return validate_scene(_build_scene(parse_toml(text, source), text))


def parse_toml(text: str, source: str) -> dict:
    """TOML text as a dictionary; a syntax error is a UserError naming `source`, on one line."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"{source}: not valid TOML: {' '.join(str(exc).split())}") from None


def scene_from_tables(tables: dict) -> Scene:
    """Build and validate a scene given as {table: {key: value}} in Python, as a scene file
    with those tables would be (the reports' and benchmarks' scenes); its `text` is the
    scene written as TOML (`scene_to_toml`)."""
    scene = validate_scene(_build_scene(tables, ""))
    return replace(scene, text=scene_to_toml(scene))


def scene_keys() -> dict:
    """Every scene key, "table.key" -> its declaration (meaning, unit, rule, choices,
    default_from, model, ...): the schema that parsing, validation, the run options and
    docs/scene.md are read from."""
    return {f"{t}.{k}": spec for t, (_, keys) in _SCHEMA.items() for k, spec in keys.items()}


SCENE_TABLES = tuple(_SCHEMA)
"""The tables of a scene file, in the order `scene_to_toml` writes them."""


def scene_to_toml(scene: Scene) -> str:
    """The scene as TOML that parses back to an equal scene, every value written out.

    What a result file stores as its `scene` attribute: the scene actually run, with
    `with_key` changes and command-line overrides, not only the file it came from.
    """
    lines = [f"title = {_toml_value(scene.title)}"] if scene.title else []
    for name in SCENE_TABLES:
        table = getattr(scene, name)
        if table is not None:
            lines.append(f"\n[{name}]")
            lines += _table_lines(table, scene.geometry.model)
    if scene.sweep:
        lines.append("\n[sweep]")
        lines += [f"{json.dumps(key)} = {_toml_value(list(values))}" for key, values in scene.sweep]
    return "\n".join(lines) + "\n"


_TABLE_LINES: dict[tuple[int, str], tuple[weakref.ref, tuple[str, ...]]] = {}
"""`_table_lines` of the tables alive, by (id, geometry.model): the scenes that `with_key`
makes share every table but the one changed, so a study's runs write only that one anew."""


def _table_lines(table, model: str) -> tuple[str, ...]:
    """The `key = value` lines of one (frozen) table of a scene of geometry.model `model`."""
    index = (id(table), model)
    known = _TABLE_LINES.get(index)
    if known is not None and known[0]() is table:
        return known[1]
    values = ((key, getattr(table, key)) for key in _written_keys(type(table), model))
    lines = tuple(f"{key} = {_toml_value(value)}" for key, value in values if value is not None)
    _TABLE_LINES[index] = (weakref.ref(table, lambda _, index=index: _TABLE_LINES.pop(index, None)),
                           lines)
    return lines


@functools.cache
def _written_keys(table: type, model: str) -> tuple[str, ...]:
    """The keys of a table class that `scene_to_toml` writes (when not None) for a scene of
    geometry.model `model`, in field order: not a key of the other model (at its default
    there, and refused if written), nor geometry.model = "yarn" (so a one-yarn scene's text
    is what it was before the fabric existed)."""
    return tuple(f.name for f in fields(table)
                 if not (f.name == "model" and model == "yarn")
                 and f.metadata["scene_key"].model in ("", model))


def _toml_value(value) -> str:
    """One TOML value: bool, int, float (repr round-trips), string, or a list of them."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, str):
        return json.dumps(value)
    return repr(value)


_VALIDATED: weakref.WeakValueDictionary[int, Scene] = weakref.WeakValueDictionary()
"""The scenes `validate_scene` passed, by id (an entry goes with its scene)."""


def validate_scene(scene: Scene) -> Scene:
    """Check every value and every combination of a Scene; return it, a fabric's
    geometry.planes left out (None) set to what runs: "fixed" on a clamped patch,
    "cell" on a periodic cell (`planes_of`), so that a result file stores it; a specimen's
    defaults likewise (`_resolve_spatial`: [friction], torsion radius, lateral keys,
    fabric side).

    Runs on parsed scenes and on scenes built in Python alike. A scene is checked once: the
    very same (frozen) object passed again returns at once, so that `run` re-checking a scene
    that `load_scene` or `with_key` made costs nothing.
    """
    if _VALIDATED.get(id(scene)) is scene:
        return scene
    kind = _kind(scene)
    scene = _RESOLVE[kind[-1]](scene)
    _check_scene(scene, kind)
    _VALIDATED[id(scene)] = scene
    return scene


def _check_scene(scene: Scene, kind: tuple) -> None:
    """The checks of `validate_scene`, those of the scene's kind (`_CHECKS`) in their order:
    UserError naming the first key that fails."""
    for check in _CHECKS[kind[-1]]:
        check(scene, kind)


def planes_of(geometry: Geometry) -> str:
    """The planes a fabric runs (docs/model.md section 10): geometry.planes, or where it is
    left out "fixed" on a clamped patch and CELL_PLANES on a periodic cell."""
    if geometry.planes is not None:
        return geometry.planes
    return CELL_PLANES if geometry.boundary == "periodic" else "fixed"


def _resolve_planes(scene: Scene) -> Scene:
    """A planar fabric scene with geometry.planes set to `planes_of` where left out."""
    g = scene.geometry
    if g.planes is not None:
        return scene
    return replace(scene, geometry=replace(g, planes=planes_of(g)))


def with_key(scene: Scene, dotted_key: str, value) -> Scene:
    """A copy of `scene` with one key (e.g. "warp.kawabata_K") set, re-validated.

    Any field of a table may be set (not only sweepable ones), but derived
    defaults resolved at parse time do not follow: setting geometry.length
    leaves weft.length, and geometry.crossings leaves weft.count, as they were; on a
    specimen, setting warp.EI leaves warp.EI_lateral, a width crossing.torsion_radius and
    contact.core_stiffness the lateral stiffnesses (`validate_scene` resolved them).
    """
    return _with_keys(scene, ((dotted_key, value),))


def expand_sweep(scene: Scene) -> list[Scene]:
    """One validated Scene per [sweep] entry, its keys applied and sweep=().

    Without a sweep, `[scene]`. Each entry keeps the whole scene's `text`.
    """
    if not scene.sweep:
        return [scene]
    base = replace(scene, sweep=())
    return [_with_keys(base, [(key, values[i]) for key, values in scene.sweep])
            for i in range(yarn_count(scene))]


def yarn_count(scene: Scene) -> int:
    """Yarns simulated together: the sweep's entries, else geometry.yarns."""
    if scene.sweep:
        return len(scene.sweep[0][1])
    return scene.geometry.yarns


# --------------------------------------------------------------------------
# Messages.


def _show(value) -> str:
    """A value as the user wrote it in TOML, on one short line."""
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, str):
        text = json.dumps(value)
    elif isinstance(value, dict):
        text = "{...}"
    elif isinstance(value, (list, tuple)):
        text = "[" + ", ".join(_show(v) for v in value) + "]"
    else:
        text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _type_name(value) -> str:
    """What a wrong value is, for a message."""
    names = {bool: "a boolean", str: "a string", dict: "a table", list: "a list",
             int: "an integer", float: "a number", datetime.date: "a date",
             datetime.time: "a time"}
    for kind, name in names.items():
        if isinstance(value, kind):
            return name
    return f"a {type(value).__name__}"


def _bad(label: str, value, what: str) -> UserError:
    """The one-line error `label = value: what`."""
    return UserError(f"{label} = {_show(value)}: {what}")


def _missing(table: str, key: str, needed: str = "") -> UserError:
    """The error for a required key left out, with its unit and what needs it."""
    return UserError(f"missing required key {table}.{key}{_units(_SCHEMA[table][1][key])}"
                     + (f" (needed with {needed})" if needed else ""))


def _unknown(label: str, candidates, allowed) -> UserError:
    """Error for an unknown key, suggesting the candidate equal but for case, else the closest."""
    same_but_case = [c for c in candidates if c.lower() == label.lower()]
    match = same_but_case or difflib.get_close_matches(label, list(candidates), n=1)
    hint = f"did you mean '{match[0]}'?" if match else "allowed: " + ", ".join(allowed)
    return UserError(f"unknown key '{label}'; {hint}")


def _unknown_top(name: str) -> UserError:
    """Error for an unknown top-level key or table; a field name (exactly one, or close to
    one and to no table) points to its table."""
    by_field = {}
    for dotted in _ALL_KEYS:
        by_field.setdefault(dotted.split(".")[1], dotted)
    if name in by_field or not difflib.get_close_matches(name, _TOP_KEYS, n=1):
        match = difflib.get_close_matches(name, list(by_field), n=1)
        if match:
            dotted = by_field[match[0]]
            return UserError(f"unknown key '{name}'; did you mean '{dotted}' "
                              f"({match[0]} under [{dotted.split('.')[0]}])?")
    return _unknown(name, _TOP_KEYS, _TOP_KEYS)


# --------------------------------------------------------------------------
# Single values.


def _convert(label: str, value, key: _Key):
    """Check one value's type and range; return it as stored (ints as float for reals)."""
    if key.kind == "floats":
        return _convert_list(label, value, key)
    if key.kind == "str":
        return _convert_str(label, value, key)
    number = _number(label, value, key)
    _check_range(label, value, key)
    return number


def _units(key: _Key) -> str:
    """" [unit]" or ""."""
    return f" [{key.unit}]" if key.unit else ""


def _number(label: str, value, key: _Key):
    """A finite number (an integer for int keys); bools and strings refused."""
    what = "an integer" if key.kind == "int" else "a number"
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise _bad(label, value, f"must be {what}{_units(key)}, not {_type_name(value)}")
    if not math.isfinite(value):
        raise _bad(label, value, f"must be a finite number{_units(key)}")
    if key.kind == "float":
        return float(value)
    if not isinstance(value, numbers.Integral):
        raise _bad(label, value, "must be an integer (write it without a decimal point)")
    return int(value)


def _check_range(label: str, value, key: _Key) -> None:
    """Apply the key's rule to a finite number: positive, non-negative or non-zero."""
    noun = "integer" if key.kind == "int" else "number"
    failed = {"positive": value <= 0, "nonnegative": value < 0,
              "nonzero": value == 0}.get(key.rule, False)
    if failed:
        adjective = {"positive": "a positive", "nonnegative": "a non-negative",
                     "nonzero": "a non-zero"}[key.rule]
        raise _bad(label, value, f"must be {adjective} {noun}{_units(key)}")


def _convert_str(label: str, value, key: _Key) -> str:
    """A string, one of key.choices when given."""
    if not isinstance(value, str):
        raise _bad(label, value, f"must be a string, not {_type_name(value)}")
    if key.choices and value not in key.choices:
        allowed = ", ".join(json.dumps(c) for c in key.choices)
        match = difflib.get_close_matches(value, key.choices, n=1)
        hint = f"; did you mean {json.dumps(match[0])}?" if match else ""
        raise _bad(label, value, f"must be one of {allowed}{hint}")
    return value


def _convert_list(label: str, value, key: _Key) -> tuple[float, ...]:
    """A non-empty list of finite numbers, as a tuple of floats."""
    if not isinstance(value, (list, tuple)) or not value:
        raise _bad(label, value, f"must be a non-empty list of numbers{_units(key)}")
    item = _Key("float", key.unit)
    return tuple(_number(f"{label}[{i}]", v, item) for i, v in enumerate(value))


# --------------------------------------------------------------------------
# From the TOML dictionary to a Scene.


def _build_scene(raw: dict, text: str) -> Scene:
    """Structure, types and defaults: the raw TOML dictionary to a Scene."""
    for name in raw:
        if name not in _TOP_KEYS:
            raise _unknown_top(name)
    tables = {name: _table(raw, name) for name in (*_SCHEMA, "sweep")}
    _check_written_kind(tables)
    sweep = _parse_sweep(tables["sweep"]) if tables["sweep"] is not None else ()
    _fill_swept(tables, sweep)
    specimen = tables["specimen"] is not None
    geometry = _build_table("geometry", tables["geometry"], specimen=specimen)
    title = _convert("title", raw.get("title", ""), _TITLE)
    built = {"geometry": geometry}
    for name in _SCHEMA:  # in order, so that the first table at fault is the one named
        if name == "weft":
            built[name] = _build_weft(tables[name], geometry, specimen)
        elif name == "load":
            built[name] = _build_load(tables[name])
        elif name != "geometry":
            built[name] = _build_optional(name, tables[name])
    given = {name: table for name, table in built.items() if table is not None}
    return Scene(title=title, sweep=sweep, text=text, **given)  # the absent at their defaults


def _table(raw: dict, name: str) -> dict | None:
    """The raw [name] table, None if absent; refuse a value that is not a table."""
    value = raw.get(name)
    if value is not None and not isinstance(value, dict):
        raise _bad(name, value, f"must be a table [{name}], not {_type_name(value)}")
    if value is None and name in _REQUIRED_TABLES:
        raise UserError(f"missing required table [{name}]")
    return value


def _check_keys(name: str, table: dict, allowed) -> None:
    """Refuse keys of [name] not in allowed, suggesting the closest valid one."""
    for key in table:
        if key not in allowed:
            raise _unknown(f"{name}.{key}", _ALL_KEYS, allowed)


def _build_table(name: str, table: dict, defaults: dict | None = None, specimen: bool = False):
    """The dataclass of [name] from its raw table; missing keys take defaults. `specimen`:
    the scene has a [specimen], which sets the layout (layout keys not required)."""
    cls, keys = _SCHEMA[name]
    _check_keys(name, table, keys)
    values = {}
    for key, spec in keys.items():
        if key in table:
            values[key] = _convert(f"{name}.{key}", table[key], spec)
        elif defaults and key in defaults:
            values[key] = defaults[key]
        elif _is_required(cls, key) or (_layout_required(spec) and not specimen):
            raise _missing(name, key)
    return cls(**values)


def _is_required(cls: type, name: str) -> bool:
    """Whether the dataclass field has no default."""
    found = next(f for f in fields(cls) if f.name == name)
    return found.default is MISSING and found.default_factory is MISSING


def _layout_required(spec: _Key) -> bool:
    """A layout key of both models, required unless a [specimen] sets the layout (one that
    another key fills, `default_from`, is filled from it)."""
    return spec.layout and not spec.model and not spec.default_from


def _build_optional(name: str, table: dict | None):
    """An optional table's dataclass, None when the table is absent."""
    return None if table is None else _build_table(name, table)


def _build_weft(table: dict | None, geometry: Geometry, specimen: bool) -> Weft | None:
    """The weft; a key left out takes its `default_from` key of [geometry] (length, count),
    none of them with a [specimen] (it sets the layout)."""
    if table is None:
        return None
    defaults = {name: getattr(geometry, spec.default_from.split(".")[1])
                for name, spec in _SCHEMA["weft"][1].items() if spec.default_from}
    return _build_table("weft", table, defaults, specimen=specimen)


def _build_load(table: dict) -> Load:
    """The load path: `values`, or `max` and `steps` (values = max k / steps)."""
    keys = _SCHEMA["load"][1]
    for key in table:
        if key.endswith("_control"):
            raise _bad(f"load.{key}", table[key], "one load.control for both families "
                       "(docs/model.md section 10): mixed control is refused")
    _check_keys("load", table, (*keys, *_LOAD_PATH))
    control = _convert("load.control", table.get("control", "force"), keys["control"])
    has_path = [k for k in _LOAD_PATH if k in table]
    if "values" in table and has_path:
        raise UserError(f"load.values and load.{has_path[0]} both given: "
                         "write the load path either as values or as max and steps")
    if "values" in table:
        return Load(control=control, values=_convert("load.values", table["values"],
                                                      keys["values"]), **_fabric_loads(table))
    if not has_path:
        raise UserError("missing required key load.values (or load.max and load.steps)")
    for key in _LOAD_PATH:
        if key not in table:
            raise UserError(f"missing required key load.{key} (given with load.{has_path[0]})")
    top = _convert("load.max", table["max"], _LOAD_PATH["max"])
    steps = _convert("load.steps", table["steps"], _LOAD_PATH["steps"])
    if steps > MAX_LOAD_STEPS:
        raise _bad("load.steps", steps, f"at most {MAX_LOAD_STEPS:,} load steps (each one is "
                   "solved, written and reported; the path alone would hold "
                   f"{32 * steps / 1e9:.3g} GB): use fewer, larger steps")
    return Load(control=control, values=tuple(top * k / steps for k in range(1, steps + 1)),
                **_fabric_loads(table))


def _fabric_loads(table: dict) -> dict:
    """The fabric's lists of [load] given (weft_values, warp_factors, weft_factors)."""
    return {key: _convert(f"load.{key}", table[key], spec)
            for _, key, spec in _keys_where(("load",), model="fabric") if key in table}


def _parse_sweep(table: dict) -> tuple[tuple[str, tuple[float, ...]], ...]:
    """[sweep] as (dotted key, values) pairs; quoted or bare dotted keys alike."""
    flat = _flatten(table)
    if not flat:
        raise UserError('[sweep] is empty: give at least one key, e.g. '
                         '"warp.kawabata_K" = [0.02, 0.2, 1.0], or remove the table')
    entries = []
    for key, values in flat.items():
        _check_sweep_key(key)
        table_name, name = key.split(".")
        unit = _SCHEMA[table_name][1][name].unit
        entries.append((key, _convert(f'sweep."{key}"', values, _Key("floats", unit))))
    return tuple(entries)


def _flatten(table: dict, prefix: str = "") -> dict:
    """{"warp": {"EA": [...]}} and {"warp.EA": [...]} both to {"warp.EA": [...]}."""
    flat = {}
    for key, value in table.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def _fill_swept(tables: dict, sweep) -> None:
    """A swept key may be left out of its (present) table: it takes entry 0."""
    for key, values in sweep:
        table_name, name = key.split(".")
        table = tables.get(table_name)
        if table is not None and name not in table:
            tables[table_name] = {**table, name: values[0]}


# --------------------------------------------------------------------------
# Checks on a Scene.


def _check_crossed(scene: Scene, kind: tuple) -> None:
    """A yarn with crossings needs its [weft]; a plain rod (geometry.crossings = 0) refuses
    the crossings' tables (`_TABLE_REFUSALS`)."""
    crossings = scene.geometry.crossings
    if crossings == 0:
        _refuse((*kind, "rod"), "rod", _given_tables(scene))
    else:
        _require_table(scene, "weft", f"geometry.crossings = {crossings} > 0")


def _require_table(scene: Scene, table: str, why: str) -> None:
    """UserError where the scene lacks [table], saying why it is needed."""
    if getattr(scene, table) is None:
        raise UserError(f"missing required table [{table}] ({why})")


def _check_fields(scene: Scene, kind: tuple) -> None:
    """Every field's type and range, as if read from TOML."""
    _convert("title", scene.title, _TITLE)
    for name, (_, keys) in _SCHEMA.items():
        table = getattr(scene, name)
        if table is None:
            continue
        for key, spec in keys.items():
            value = getattr(table, key)
            if value is not None:
                _convert(f"{name}.{key}", value, spec)


def _check_segments(scene: Scene, kind: tuple) -> None:
    """segments a multiple of 2 x crossings; a plain rod is straight, segments >= 2."""
    geometry = scene.geometry
    n, crossings = geometry.segments, geometry.crossings
    if crossings == 0:
        if n < 2:
            raise _bad("geometry.segments", n, "a plain rod (geometry.crossings = 0) "
                       "needs at least 2 segments")
        if geometry.amplitude != 0:
            raise _bad("geometry.amplitude", geometry.amplitude, "a plain rod "
                       "(geometry.crossings = 0) is straight; amplitude must be 0")
        return
    step = 2 * crossings
    if n % step:
        nearest = max(step, round(n / step) * step)
        raise _bad("geometry.segments", n, f"must be a positive multiple of 2 x "
                   f"geometry.crossings = {step} (crossings = {crossings}); "
                   f"nearest valid: {nearest}")


# --------------------------------------------------------------------------
# The kinds of scene: each refuses the tables and keys the schema declares for another.


def _kind(scene: Scene) -> tuple[str, ...]:
    """The facets of a scene's kind that `_KEY_REFUSALS` and `_TABLE_REFUSALS` name: "fabric"
    with "specimen" (its [specimen] sets the layout) or else "planar"; otherwise "yarn"
    (whatever geometry.model says: another value is refused with the values). The last facet
    names the kind's rules (`_RESOLVE`, `_CHECKS`). A fabric's kinematics and its [specimen]
    go together (`_check_kinematics`). A plain rod's facet, "rod", is added where its tables
    are checked (`_check_crossed`). The one place that asks which kind a scene is before it
    is valid (`dynfab.model.builders.scene_kind` after)."""
    if scene.geometry.model != "fabric":
        return ("yarn",)
    _check_kinematics(scene.geometry.kinematics, scene.specimen is not None)
    return ("fabric", "specimen" if scene.specimen is not None else "planar")


def _refuse(kind: tuple, facet: str, given) -> None:
    """Where the scene's `kind` has `facet`, refuse the first of `given` that the facet refuses:
    a table of `_TABLE_REFUSALS`, or a key declared as `_KEY_REFUSALS[facet]` says.

    `given`: (table, key, value) in the order to check, key None for a table. Each facet is
    checked where the scene's rules have always met it: the file's model before its tables
    are read, the specimen's layout first, the rod's tables with the required ones, the
    models' tables and keys after the values, a planar fabric's spatial keys last.
    """
    if facet not in kind:
        return
    for table, key, value in given:
        if key is None:
            if facet in _TABLE_REFUSALS.get(table, {}):
                raise UserError(f"[{table}] given but {_GIVEN_BUT[facet]}: "
                                f"{_TABLE_REFUSALS[table][facet]}")
        elif _refused_by(facet, spec := _SCHEMA[table][1][key]):
            raise UserError(_KEY_REFUSALS[facet][2].format(key=f"{table}.{key}",
                                                          value=_show(value), hint=spec.hint))


def scene_takes(scene: Scene, table: str, key: str) -> bool:
    """Whether a scene of `scene`'s kind takes `table.key`: no facet of its kind refuses it
    (`_KEY_REFUSALS`)."""
    spec = _SCHEMA[table][1][key]
    return not any(_refused_by(facet, spec) for facet in _kind(scene))


def _refused_by(facet: str, spec: _Key) -> bool:
    """Whether the facet of a scene's kind refuses the key declared `spec` (`_KEY_REFUSALS`)."""
    field_name, declared, _ = _KEY_REFUSALS.get(facet, ("", None, ""))
    return bool(field_name) and getattr(spec, field_name) == declared


def _given_tables(scene: Scene) -> list[tuple]:
    """(table, None, value) of the tables of `_TABLE_REFUSALS` that `scene` has, in its order."""
    return [(name, None, getattr(scene, name)) for name in _TABLE_REFUSALS
            if getattr(scene, name) not in (None, ())]


def _given_keys(scene: Scene, tables=tuple(_SCHEMA)) -> list[tuple]:
    """(table, key, value) of the keys that `scene` sets away from their defaults (not None
    where None is the default), table by table in the order of `tables`."""
    given = []
    for name, table in ((name, getattr(scene, name)) for name in tables):
        if table is not None:
            given += [(name, key, getattr(table, key)) for key, default in _DEFAULTS[name].items()
                      if _away(getattr(table, key), default)]
    return given


def _away(value, default) -> bool:
    """Whether a key's value is not its default (None: whether it is given)."""
    return value is not None if default is None else value != default


@functools.cache
def _keys_where(tables=tuple(_SCHEMA), **declared) -> tuple[tuple[str, str, _Key], ...]:
    """(table, key, spec) of the keys of `tables` declared so (e.g. layout=True, model="")."""
    return tuple((t, k, spec) for t in tables for k, spec in _SCHEMA[t][1].items()
                 if all(getattr(spec, name) == value for name, value in declared.items()))


def _written(tables: dict, names) -> list[tuple]:
    """(table, None, value) of the tables `names` that a file's `tables` give."""
    return [(name, None, tables[name]) for name in names if tables.get(name) is not None]


def _check_written_kind(tables: dict) -> None:
    """Refuse, as written in the file, a table or key of the other model (docs/model.md
    section 10: [pullout] and [sweep] first, then the keys, then [specimen] and [crossing],
    named by their first key where they hold one); then a fabric's kinematics without its
    [specimen] or the reverse (`_check_kinematics`), before a missing layout key is looked for."""
    geometry = tables["geometry"]
    kind = (geometry.get("model", "yarn"),)
    keys = [(t, k, tables[t][k]) for t, k, _ in _keys_where() if k in (tables[t] or {})]
    given = [*_written(tables, ("pullout", "sweep")), *keys, *_written(tables, _TABLE_REFUSALS)]
    for facet in ("yarn", "fabric"):
        _refuse(kind, facet, given)
    if "fabric" in kind:
        spec = _SCHEMA["geometry"][1]["kinematics"]
        kinematics = _convert("geometry.kinematics", geometry.get("kinematics", "planar"), spec)
        _check_kinematics(kinematics, tables["specimen"] is not None)


def _check_fabric(scene: Scene, kind: tuple) -> None:
    """What a fabric scene must be (docs/model.md section 10): none of the one-yarn model's
    tables and keys (weft.tension named before geometry.yarns), as woven, the weft's chain
    keys; then a [specimen] (`_check_specimen`) or a planar patch (`_check_planar`)."""
    g, weft = scene.geometry, scene.weft
    _refuse(kind, "fabric", [*_given_tables(scene), *_given_keys(scene, ("weft", *_SCHEMA))])
    if g.reference != "as_woven":
        raise _bad("geometry.reference", g.reference, "a fabric's stress-free state is as "
                   "woven (docs/model.md section 10); use \"as_woven\"")
    if weft.EA is None:
        raise _missing("weft", "EA", _FABRIC)


def _check_planar(scene: Scene, kind: tuple) -> None:
    """A planar patch or cell: its weft chains, no spatial key, a pull-out's and a periodic
    cell's rules, one load factor per yarn, crossings that slide on a clamped patch with
    fixed planes."""
    g, weft = scene.geometry, scene.weft
    if weft.segments is None:
        raise _missing("weft", "segments", _FABRIC)
    _refuse(kind, "planar", _given_keys(scene))
    if weft.segments % (2 * weft.count):
        step = 2 * weft.count
        raise _bad("weft.segments", weft.segments, f"must be a positive multiple of 2 x "
                   f"weft.count = {step}; nearest valid: {max(step, round(weft.segments / step) * step)}")
    if scene.pullout is not None:
        _check_pullout(scene)
    if g.boundary == "periodic":
        _check_periodic(scene)
    elif g.planes == CELL_PLANES:
        raise _bad("geometry.planes", g.planes, "the planes of a periodic cell "
                   "(geometry.boundary = \"periodic\"); a clamped patch's are \"fixed\" or "
                   "\"affine\"")
    _check_fabric_lists(scene)


# --------------------------------------------------------------------------
# The spatial fabric and its specimens (docs/model.md section 11).


def _check_layout(scene: Scene, kind: tuple) -> None:
    """The layout keys (`_Key.layout`) are refused with a [specimen], which sets the layout,
    and those of both models required where the kind takes them (a one-yarn scene's
    [specimen] is refused later, with the fabric's keys; a fabric's kinematics and [specimen]
    go together, `_kind`)."""
    _refuse(kind, "specimen", _given_keys(scene))
    for table, key, spec in _keys_where(layout=True, model=""):
        if (not any(_refused_by(facet, spec) for facet in kind) and getattr(scene, table)
                is not None and getattr(getattr(scene, table), key, None) is None):
            raise _missing(table, key)


def _check_kinematics(kinematics: str, specimen: bool) -> None:
    """A fabric's spatial kinematics and its [specimen] go together (docs/model.md
    section 11)."""
    if kinematics == "spatial" and not specimen:
        raise _bad("geometry.kinematics", kinematics, "spatial kinematics runs a [specimen] "
                   "test (bias_extension or picture_frame, docs/model.md section 11); add a "
                   "[specimen] table")
    if specimen and kinematics != "spatial":
        raise UserError(f"[specimen] given but geometry.kinematics = {_show(kinematics)}: a "
                        f"specimen is sheared in plane (docs/model.md section 11); set "
                        f"{_SPATIAL}")


def _check_specimen(scene: Scene, kind: tuple) -> None:
    """A [specimen] (spatial kinematics, checked before): a finite piece of fabric, one test,
    sized for its test, both families' lateral keys, a preload, clamp displacement alone."""
    g = scene.geometry
    if g.boundary != "clamped":
        raise _bad("geometry.boundary", g.boundary, "a [specimen] is a finite piece of fabric "
                   "held by its clamps or frame, not a periodic cell; remove boundary or write "
                   "\"clamped\"")
    if g.planes is not None:
        raise _bad("geometry.planes", g.planes, "the yarns' planes are the planar fabric's "
                   "(docs/model.md section 10); a specimen's yarns move in x, y and z: remove it")
    if scene.pullout is not None:
        raise UserError("[pullout] given with [specimen]: a scene is one test, a pull-out of a "
                        "planar patch or an in-plane shear specimen; remove one")
    _check_specimen_size(scene.specimen)
    for family in (scene.warp, scene.weft):
        _check_family_lateral(family)
    _check_preload(scene.crossing)
    _check_specimen_load(scene.load)


def _check_specimen_size(specimen: Specimen) -> None:
    """Bias extension: W and H >= 2W, no side; picture frame: L >= L_fabric, no W, H."""
    bias = specimen.test == "bias_extension"
    needed, refused = ((("width", "height"), ("side", "fabric_side")) if bias
                       else (("side",), ("width", "height")))
    test = f"specimen.test = {_show(specimen.test)}"
    for key in refused:
        value = getattr(specimen, key)
        if value is not None:
            raise _bad(f"specimen.{key}", value, f"not a key of {test}; remove it")
    for key in needed:
        if getattr(specimen, key) is None:
            raise _missing("specimen", key, test)
    if bias and specimen.height < 2 * specimen.width:
        raise _bad("specimen.height", specimen.height, f"must be at least 2 x specimen.width = "
                   f"{2 * specimen.width:g} m: H/W = {specimen.height / specimen.width:.3g} < 2 "
                   "(a bias-extension specimen needs H >= 2W, docs/model.md section 11)")
    if not bias and specimen.fabric_side > specimen.side:
        raise _bad("specimen.fabric_side", specimen.fabric_side, "must be at most specimen.side "
                   f"= {specimen.side!r} m: the sheared fabric lies inside the frame")


def _check_family_lateral(family: Warp | Weft) -> None:
    """A specimen's family: its spacing, width (below the spacing) and crimp given."""
    name = "warp" if isinstance(family, Warp) else "weft"
    for key in ("spacing", "width", "amplitude"):
        if getattr(family, key) is None:
            raise _missing(name, key, "[specimen]")
    if family.width >= family.spacing:
        raise _bad(f"{name}.width", family.width, f"must be below {name}.spacing = "
                   f"{family.spacing!r} m: neighbouring {name}s would overlap as woven")
    _check_compaction(name, family)


COMPACTION_KEYS = ("fibre_modulus", "fibre_volume_fraction", "packing_limit", "fibre_waviness")
"""A family's keys of Gutowski's lateral compaction (docs/model.md 11.5): all or none."""
HEXAGONAL_PACKING = math.pi / (2.0 * math.sqrt(3.0))
"""0.9069: the densest packing of parallel round fibres."""


def _check_compaction(name: str, family: Warp | Weft) -> None:
    """The compaction keys all given or all left out; V0 < V_a <= hexagonal packing."""
    given = [key for key in COMPACTION_KEYS if getattr(family, key) is not None]
    if given and len(given) < len(COMPACTION_KEYS):
        missing = ", ".join(f"{name}.{key}" for key in COMPACTION_KEYS if key not in given)
        raise UserError(f"{name}.{given[0]} given without {missing}: Gutowski's lateral "
                        f"compaction needs {', '.join(COMPACTION_KEYS)} (docs/model.md 11.5); "
                        "give them all or none")
    if not given:
        return
    if family.packing_limit > HEXAGONAL_PACKING:
        raise _bad(f"{name}.packing_limit", family.packing_limit, "must be at most "
                   f"{HEXAGONAL_PACKING:.4f}, the hexagonal packing of round fibres")
    if family.fibre_volume_fraction >= family.packing_limit:
        raise _bad(f"{name}.fibre_volume_fraction", family.fibre_volume_fraction, "must be "
                   f"below {name}.packing_limit = {family.packing_limit!r}: the yarn as woven "
                   "is looser than its fibres can pack")


_NO_PRELOAD = "a specimen needs crossing.preload > 0: without it every friction limit is zero"


def _check_preload(crossing: Crossing | None) -> None:
    """R_p > 0 on a specimen (docs/model.md section 11: the as-woven fabric is stress-free)."""
    if crossing is None:
        raise UserError(f"missing table [crossing]: {_NO_PRELOAD}")
    if crossing.preload == 0:
        raise _bad("crossing.preload", crossing.preload, _NO_PRELOAD)


def _check_specimen_load(load: Load) -> None:
    """A specimen is loaded by its clamp (frame corner) displacement, load.values, alone."""
    if load.control != "displacement":
        raise _bad("load.control", load.control, "a specimen is loaded by its clamp "
                   'displacement: load.control = "displacement"')
    for _, key, _ in _keys_where(("load",), model="fabric"):
        value = getattr(load, key)
        if value is not None:
            raise _bad(f"load.{key}", value, "a specimen is loaded by its clamp (frame corner) "
                       "displacement alone, load.values; remove it")


def _resolve_spatial(scene: Scene) -> Scene:
    """A specimen scene with its resolved defaults (docs/model.md section 11), so that a result
    file stores what runs: [friction] the paper's law (the `Specimen` decision),
    crossing.torsion_radius 0.3826 x the smaller width, each family's EI_lateral its EI and
    lateral_stiffness the core stiffness, specimen.fabric_side the side. Values the checks
    will refuse (missing, not numbers) are left for them."""
    changes = {}
    if scene.friction is None:
        changes["friction"] = PAPER_FRICTION
    core = scene.contact.core_stiffness if scene.contact is not None else None
    if core is None and _lateral_stiffness_unset(scene):
        core = DEFAULT_CORE_STIFFNESS
    for name in ("warp", "weft"):
        family = getattr(scene, name)
        if family is not None:
            changes[name] = _resolve_family(family, core)
    if scene.crossing is not None:
        changes["crossing"] = _resolve_crossing(scene.crossing, scene.warp, scene.weft)
    s = scene.specimen
    if s.fabric_side is None and s.side is not None and s.test == "picture_frame":
        changes["specimen"] = replace(s, fabric_side=s.side)
    return replace(scene, **changes)


def _resolve_crossing(crossing: Crossing, warp, weft) -> Crossing:
    """shear_stiffness 0 and torsion_radius 0.3826 x the smaller width, where left out."""
    changes = {}
    if crossing.shear_stiffness is None:
        changes["shear_stiffness"] = 0.0
    widths = [getattr(f, "width", None) for f in (warp, weft)]
    if crossing.torsion_radius is None and all(_is_real(w) for w in widths):
        changes["torsion_radius"] = TORSION_RADIUS_PER_WIDTH * min(widths)
    return replace(crossing, **changes)


def _lateral_stiffness_unset(scene: Scene) -> bool:
    """Whether a family leaves lateral_stiffness to its default."""
    return any(f is not None and f.lateral_stiffness is None for f in (scene.warp, scene.weft))


def _resolve_family(family: Warp | Weft, core: float | None) -> Warp | Weft:
    """EI_lateral = EI and lateral_stiffness = the core stiffness, where left out."""
    changes = {}
    if family.EI_lateral is None:
        changes["EI_lateral"] = family.EI
    if family.lateral_stiffness is None:
        changes["lateral_stiffness"] = core
    return replace(family, **changes) if changes else family


def _is_real(value) -> bool:
    """A finite real number (not a bool), as a resolved default may be computed from."""
    return (isinstance(value, numbers.Real) and not isinstance(value, bool)
            and math.isfinite(value))


def _check_periodic(scene: Scene) -> None:
    """A unit cell: its planes move with it, even yarn counts (the 2 x 2 plain-weave
    repeat), no gravity."""
    planes = scene.geometry.planes
    if planes != CELL_PLANES:
        raise _bad("geometry.planes", planes, "a periodic cell's planes always move with the "
                   f"cell (docs/model.md section 10); leave the key out or write "
                   f"\"{CELL_PLANES}\"")
    for dotted, count, what in (("weft.count", scene.weft.count, "warps"),
                                ("geometry.crossings", scene.geometry.crossings, "wefts")):
        if count % 2:
            raise _bad(dotted, count, f"a periodic cell (geometry.boundary = \"periodic\") "
                       f"needs an even number of {what}: the plain-weave repeat is 2 x 2")
    if scene.gravity is not None:
        raise UserError("[gravity] given with geometry.boundary = \"periodic\": a periodic "
                        "cell has no gravity (docs/model.md section 10); remove [gravity] or use "
                        "a clamped patch")


def _check_fabric_lists(scene: Scene) -> None:
    """weft_values as long as values; one factor per yarn of its family."""
    load = scene.load
    expected = (("weft_values", len(load.values), "load.values has", "", "load step"),
                ("warp_factors", scene.weft.count, "weft.count says there are", " warps", "warp"),
                ("weft_factors", scene.geometry.crossings, "geometry.crossings says there are",
                 " wefts", "weft"))
    for key, count, what, noun, per in expected:
        values = getattr(load, key)
        if values is not None and len(values) != count:
            raise UserError(f"load.{key} has {len(values)} entries but {what} {count}{noun}: "
                            f"give one per {per}")


def _check_pullout(scene: Scene) -> None:
    """A pull-out: a clamped patch with fixed planes (checked first: a pull-out of a periodic
    cell is refused for its boundary, whatever else it says), a warp of the patch,
    displacement control."""
    warp, g = scene.pullout.warp, scene.geometry
    if g.boundary != "clamped" or g.planes != "fixed":
        key, value = (("geometry.boundary", g.boundary) if g.boundary != "clamped"
                      else ("geometry.planes", g.planes))
        raise _bad(key, value, "a pull-out is a clamped patch with fixed planes "
                   "(docs/model.md section 10)")
    if warp > scene.weft.count:
        raise _bad("pullout.warp", warp, f"must name a warp 1..weft.count = {scene.weft.count}")
    if scene.load.control != "displacement":
        raise _bad("load.control", scene.load.control, "a pull-out is displacement-"
                   "controlled (docs/model.md section 10); use \"displacement\"")
    if scene.load.warp_factors is not None:
        raise _bad("load.warp_factors", scene.load.warp_factors, "a pull-out sets them "
                   "(the pulled warp 1, the others held); remove it")


def _check_weft_tension(scene: Scene, kind: tuple) -> None:
    """P_we > -Pcr_we = -pi^2 EI_we / L_we^2: the weft must not buckle (docs/model.md section 3);
    a plain rod has no weft."""
    weft = scene.weft
    if weft is None:
        return
    limit = -math.pi**2 * weft.EI / weft.length**2
    if weft.tension <= limit:
        raise _bad("weft.tension", weft.tension, f"must be > {limit:.6g} N = -pi^2 weft.EI / "
                   "weft.length^2, where the weft buckles (docs/model.md section 3)")


def _check_dynamic(dynamic: Dynamic) -> None:
    """Refuse [dynamic] combinations that cannot work or would be ignored."""
    if dynamic.mode == "transient":
        _check_transient(dynamic)
    else:
        for key in ("duration", "output_interval"):
            value = getattr(dynamic, key)
            if value is not None:
                raise _bad(f"dynamic.{key}", value,
                           'only used with dynamic.mode = "transient"')
    _check_method_damping(dynamic)
    damping = dynamic.damping_used()
    if dynamic.damping_coefficient is not None and damping != "viscous":
        raise _bad("dynamic.damping_coefficient", dynamic.damping_coefficient,
                   f'only used with dynamic.damping = "viscous" (damping is "{damping}")')


def check_dynamic_options(dynamic: Dynamic) -> Dynamic:
    """The rules that combine [dynamic] keys (mode with its keys, method with damping,
    damping with its coefficient), exactly as `validate_scene` applies them; returns
    `dynamic` unchanged. For solver options built in Python and given to `DynamicSolver`
    apart from a scene; each value's own range stays the caller's (code may set
    accuracy = inf to turn the accuracy target off)."""
    _check_dynamic(dynamic)
    return dynamic


def _check_method_damping(dynamic: Dynamic) -> None:
    """semi_implicit takes neither FIRE (which drives an explicit integrator) nor kinetic
    damping (its rejected steps are undone instead, docs/model.md section 5): refused, not
    ignored."""
    if dynamic.method != "semi_implicit" or dynamic.damping not in ("fire", "kinetic"):
        return
    why = ("FIRE drives an explicit integrator" if dynamic.damping == "fire" else
           "its rejected time steps are undone instead of damped")
    raise _bad("dynamic.damping", dynamic.damping, 'not available with dynamic.method = '
               f'"semi_implicit" ({why}); use "viscous" or leave damping unset')


def _check_transient(dynamic: Dynamic) -> None:
    """Transient: physical masses, viscous damping, duration >= output_interval > 0."""
    if dynamic.masses == "fictitious":
        raise _bad("dynamic.masses", dynamic.masses, 'not allowed with dynamic.mode = '
                   '"transient", which uses the physical masses')
    if dynamic.damping in ("kinetic", "fire"):
        raise _bad("dynamic.damping", dynamic.damping, 'not allowed with dynamic.mode = '
                   '"transient"; use "viscous" (the default)')
    for key in ("duration", "output_interval"):
        if getattr(dynamic, key) is None:
            raise _missing("dynamic", key, 'dynamic.mode = "transient"')
    if dynamic.output_interval > dynamic.duration:
        raise _bad("dynamic.output_interval", dynamic.output_interval,
                   f"must be <= dynamic.duration = {dynamic.duration!r} [s]")


def _check_sweep_key(key: str) -> None:
    """Refuse an unknown or unsweepable [sweep] key."""
    if key in _SWEEPABLE:
        return
    if key in _ALL_KEYS:
        raise UserError(f'sweep."{key}": this key cannot be swept; sweepable are '
                         f"{_sweepable_text()}")
    match = difflib.get_close_matches(key, _SWEEPABLE, n=1)
    hint = f"; did you mean 'sweep.\"{match[0]}\"'?" if match else ""
    raise UserError(f"unknown key 'sweep.\"{key}\"'{hint}")


def _sweepable_text() -> str:
    """The sweepable keys in words: a table whose real-valued keys all are, by its name."""
    single, tables = [], []
    for table, (_, keys) in _SCHEMA.items():
        swept = [name for name, spec in keys.items() if spec.sweepable]
        reals = [name for name, spec in keys.items() if spec.kind == "float"
                 and not _refused_by("yarn", spec)]  # a sweep's scene is one-yarn
        if swept and swept == reals:
            tables.append(f"[{table}]")
        else:
            single += [f"{table}.{name}" for name in swept]
    words = single + ([f"the real-valued keys of {_and(tables)}"] if tables else [])
    return _and(words)


def _and(items: list[str]) -> str:
    """"a", "a and b", "a, b and c"."""
    return ", ".join(items[:-1]) + " and " + items[-1] if len(items) > 1 else "".join(items)


def _check_sweep(scene: Scene, kind: tuple) -> None:
    """[sweep]: yarns = 1, sweepable keys of present tables, equal lengths, valid entries."""
    if not scene.sweep:
        return
    if scene.geometry.yarns != 1:
        raise _bad("geometry.yarns", scene.geometry.yarns, "a scene with a [sweep] "
                   "simulates one yarn per entry; remove yarns or the sweep")
    first_key, first = scene.sweep[0]
    for key, values in scene.sweep:
        _check_sweep_key(key)
        _convert(f'sweep."{key}"', values, _Key("floats"))
        table = key.split(".")[0]
        if getattr(scene, table) is None:
            raise UserError(f'sweep."{key}": the scene has no [{table}] table; '
                             f"add one to sweep its keys")
        if len(values) != len(first):
            raise UserError(f'sweep."{key}" has {len(values)} entries but sweep.'
                             f'"{first_key}" has {len(first)}: all sweep lists must '
                             "have the same length")
    _check_sweep_entries(scene)


def _check_sweep_entries(scene: Scene) -> None:
    """Each entry validated exactly as if its values were written in their tables."""
    base = replace(scene, sweep=())
    for i in range(yarn_count(scene)):
        try:
            _with_keys(base, [(key, values[i]) for key, values in scene.sweep])
        except UserError as exc:
            raise UserError(f"sweep entry {i}: {exc}") from None


def _check_some_weft(scene: Scene, kind: tuple) -> None:
    """A fabric has at least one weft (geometry.crossings > 0 where the layout is written)."""
    if scene.geometry.crossings == 0:
        raise _bad("geometry.crossings", 0, f"a fabric ({_FABRIC}) needs at least one weft")


def _check_specimen_weft(scene: Scene, kind: tuple) -> None:
    """A specimen's weft family is its [weft] table."""
    _require_table(scene, "weft", "needed with [specimen]")


def _refuse_fabric_tables(scene: Scene, kind: tuple) -> None:
    """A one-yarn scene: none of the fabric's tables, nor its keys (one set to None is left
    out)."""
    _refuse(kind, "yarn", [*_given_tables(scene),
                           *(item for item in _given_keys(scene) if item[2] is not None)])


def _check_dynamic_table(scene: Scene, kind: tuple) -> None:
    """[dynamic]'s combinations (`_check_dynamic`)."""
    _check_dynamic(scene.dynamic)


def _unchanged(scene: Scene) -> Scene:
    return scene


_RESOLVE = {"yarn": _unchanged, "planar": _resolve_planes, "specimen": _resolve_spatial}
"""The last facet of a scene's kind (`_kind`) -> the defaults it resolves before its checks,
so that a result file stores what runs."""

_CHECKS = {
    "yarn": (_check_layout, _check_crossed, _check_fields, _check_segments, _check_weft_tension,
             _refuse_fabric_tables, _check_dynamic_table, _check_sweep),
    "planar": (_check_layout, _check_some_weft, _check_crossed, _check_fields, _check_segments,
               _check_weft_tension, _check_fabric, _check_planar, _check_dynamic_table,
               _check_sweep),
    "specimen": (_check_layout, _check_specimen_weft, _check_fields, _check_fabric,
                 _check_specimen, _check_dynamic_table, _check_sweep),
}
"""The last facet of a scene's kind (`_kind`) -> its checks, each check(scene, kind), in the
order a scene's faults are named: the layout first, the tables present, every value, then
the rules that combine keys (a one-yarn scene's, a fabric's and a planar patch's or a
specimen's), [dynamic] and [sweep] last. UserError naming the first key that fails."""


def _with_keys(scene: Scene, items) -> Scene:
    """Set several dotted keys at once, then validate the whole scene once."""
    changes = {}
    for dotted, value in items:
        table_name, name, key = _field_of(dotted)
        table = changes.get(table_name) or getattr(scene, table_name)
        if table is None:
            raise UserError(f"{dotted}: the scene has no [{table_name}] table")
        changes[table_name] = replace(table, **{name: _convert(dotted, value, key)})
    return validate_scene(replace(scene, **changes))


def _field_of(dotted: str) -> tuple[str, str, _Key]:
    """(table, field, key spec) of a dotted key such as "warp.EA"."""
    table_name, _, name = dotted.partition(".")
    keys = _SCHEMA.get(table_name, (None, {}))[1]
    if name not in keys:
        raise _unknown(dotted, _FIELD_KEYS, _FIELD_KEYS)
    return table_name, name, keys[name]


# --------------------------------------------------------------------------
# The key table of docs/scene.md, written from the schema.

_RULE_TEXT = {"": "", "positive": " > 0", "nonnegative": " >= 0", "nonzero": " != 0"}
_ONLY = {("fabric", False): "(fabric only) ", ("yarn", False): "(one-yarn model only) ",
         ("fabric", True): "(spatial fabric only) "}
"""A key's (model, spatial) declaration as its row's meaning starts."""
_KIND_TEXT = {"float": "number", "int": "integer", "str": "string", "floats": "list of numbers"}


def run_flag(option: str) -> str:
    """The `dynfab run` flag of a run option: max_steps -> --max-steps."""
    return "--" + option.replace("_", "-")


def markdown_table() -> str:
    """docs/scene.md: every scene key with its unit, rule, default, roles and meaning.

    Written from the dataclass fields' metadata, the one place a key is described;
    `python -m dynfab.scene --markdown` prints it.
    """
    lines = ["# Scene keys", "",
             "<!-- Generated by `python -m dynfab.scene --markdown` from the fields of "
             "dynfab/scene.py; do not edit (tests/test_scene.py checks it). -->", "",
             "A scene is a TOML file in SI units. Every key of every table, with the rule its "
             "value must obey; *required*: when its table is given; *sweep*: a `[sweep]` may "
             "vary it; *flag*: the `dynfab run` flag (and `dynfab.run` keyword) that "
             "overrides it.", "",
             f"Top level: `title`, {_allowed(_TITLE)}, default `\"\"`: {_TITLE.doc}."]
    for name, (cls, keys) in _SCHEMA.items():
        lines += ["", f"## [{name}]", "", f"{cls.__doc__.splitlines()[0]} {_presence(name)}", "",
                  "| key | unit | allowed | default | sweep | flag | meaning |",
                  "| --- | --- | --- | --- | --- | --- | --- |"]
        defaults = {f.name: f.default for f in fields(cls)}
        for key_name, spec in keys.items():
            lines.append(_row(f"{name}.{key_name}", spec, _default_text(defaults[key_name], spec)))
        if name == "load":
            lines += [_row(f"load.{k}", spec, "-") for k, spec in _LOAD_PATH.items()]
    lines += ["", "## [sweep]", "",
              'Zipped lists of values, one batched yarn per entry (`"warp.kawabata_K" = '
              '[0.02, 0.2, 1.0]`); sweepable are ' + _sweepable_text() + "."]
    return "\n".join(lines) + "\n"


def _presence(table: str) -> str:
    """When a table is required, optional or refused."""
    if table in _REQUIRED_TABLES:
        return "Required."
    if table == "pullout":
        return 'Optional; only with geometry.model = "fabric" (not with `[specimen]`).'
    if table == "specimen":
        return (f'Optional; only with geometry.model = "fabric" and {_SPATIAL}, which requires '
                "it. It sets the layout: a key whose default says \"refused with `[specimen]`\" "
                "is refused with it.")
    if table == "crossing":
        return ('Optional; only with geometry.model = "fabric"; a `[specimen]` needs it (a '
                "preload > 0).")
    text = ("Required when geometry.crossings > 0 or with `[specimen]`" if table == "weft"
            else "Optional")
    if "rod" in _TABLE_REFUSALS.get(table, {}):
        text += "; a plain rod (geometry.crossings = 0) refuses it"
    if table == "friction":
        f = PAPER_FRICTION
        text += (f"; a `[specimen]` without it takes the paper's law (alpha = {f.alpha:g}, beta = "
                 f"{f.beta:g} N/m^2, contact_length = {f.contact_length:g} m, fiber_radius = "
                 f"{f.fiber_radius:g} m; docs/model.md section 7); alpha = beta = 0 written "
                 "out switches it off")
    return text + "."


def _row(dotted: str, spec: _Key, default: str) -> str:
    """One table row."""
    table, name = dotted.split(".")
    flag = f"`{run_flag(name)}`" if spec.option else ""
    only = _ONLY.get((spec.model, spec.spatial), "")
    cells = (f"`{dotted}`", spec.unit, _allowed(spec), default,
             "yes" if spec.sweepable else "", flag, only + spec.doc)
    return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"


def _allowed(spec: _Key) -> str:
    """The values a key takes, in words."""
    if spec.choices:
        return ", ".join(f"`{json.dumps(c)}`" for c in spec.choices)
    return _KIND_TEXT[spec.kind] + _RULE_TEXT[spec.rule]


def _default_text(default, spec: _Key) -> str:
    """A field's default as written in TOML; required, none, or another key's value."""
    if spec.layout:
        base = (f"`{spec.default_from}`" if spec.default_from
                else {"": "required"}.get(spec.model, "none"))
        return base + "; refused with `[specimen]`"
    if spec.default_from:
        return f"`{spec.default_from}`"
    if spec.default_doc:
        return spec.default_doc
    if default is MISSING:
        return "required"
    return "none" if default is None else f"`{_toml_value(default)}`"


if __name__ == "__main__":
    import sys

    if sys.argv[1:] != ["--markdown"]:
        print("usage: python -m dynfab.scene --markdown  (prints docs/scene.md)", file=sys.stderr)
        raise SystemExit(2)
    sys.stdout.write(markdown_table())
