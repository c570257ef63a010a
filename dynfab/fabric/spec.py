"""Parameters of a woven fabric (docs/model.md section 10), SI units, as plain frozen dataclasses.

Scene-file parsing comes later; a `FabricSpec` is what a parser will produce.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, kw_only=True)
class Family:
    """One yarn family (the warps or the wefts): every yarn of it alike
    (docs/model.md section 10)."""

    length: float
    """Yarn length [m] along its in-plane axis (L for warps, L_we for wefts)."""
    segments: int
    """Segments per yarn (N or M), a multiple of twice the other family's count."""
    amplitude: float
    """As-woven crimp amplitude A [m] (0: a straight yarn)."""
    EA: float
    """Extension stiffness [N]."""
    EI: float
    """Bending stiffness [N m^2]."""
    kawabata_C: float
    """Kawabata's maximum compression C [m] (docs/model.md section 3, paper eqs. 6-8)."""
    kawabata_K: float
    """Kawabata's K [m/N]; a = K / Lc with Lc the half-wave arc length (docs/model.md section 3)."""
    linear_density: float = 3e-5
    """rho_l [kg/m], for gravity's physical masses rho_l lbar_i (docs/model.md section 2)."""


@dataclass(frozen=True, kw_only=True)
class Friction:
    """Gralen's friction limit with its onset, as stick-slip (docs/model.md sections 4 and 10)."""

    alpha: float
    """Gralen alpha [-]."""
    beta: float
    """Gralen beta [N/m^2]."""
    contact_length: float
    """ell [m]."""
    fiber_radius: float
    """r_f [m]."""
    onset_force: float = 1e-5
    """R_0 [N]: the constant term sets in as 1 - exp(-R/R_0); 0 is the literal jump law."""
    stick_stiffness: float | None = None
    """k_t [N/m]; None: the smaller family's EA / segment length (docs/model.md section 10)."""


@dataclass(frozen=True, kw_only=True)
class FabricSpec:
    """A woven fabric patch and its load path (docs/model.md section 10)."""

    warp: Family
    """The warp yarns, along x, in the planes y = Y_k."""
    weft: Family
    """The weft yarns, along y, in the planes x = X_j."""
    warps: int
    """n_wa, the number of warp yarns (= crossings per weft)."""
    wefts: int
    """n_we, the number of weft yarns (= crossings per warp)."""
    core_stiffness: float = 1e5
    """k_c [N/m], the yarns' core stiffness in series with both Kawabata laws; inf: none
    (then Kawabata's wall at C_wa + C_we is a hard limit, energy +inf beyond)."""
    friction: Friction | None = None
    """None: no friction."""
    gravity: float | None = None
    """g [m/s^2] along -z on the physical masses (docs/model.md section 2); None: none. Refused on
    the periodic cell (docs/model.md section 10)."""
    boundary: str = "clamped"
    """"clamped" (a finite patch) or "periodic" (a unit cell; warps and wefts even)."""
    planes: str = "fixed"
    """"fixed": X_j, Y_k at their as-woven values; "affine": they move with the patch's
    mean stretch, X_j = (j - 1/2)(L + u_wa)/n_we, u_wa the warps' mean end displacement
    (likewise Y_k); "cell" (a periodic cell only): they move with the cell. On the periodic
    cell the planes move with the cell whatever this says (a scene says "cell" there:
    `dynfab.scene` refuses the others)."""
    control: str = "force"
    """"force" (values are end forces per yarn [N]) or "displacement" (end displacements [m])."""
    warp_values: tuple[float, ...] = ()
    """The load path for each warp yarn (steps,) [N or m]."""
    weft_values: tuple[float, ...] | None = None
    """The load path for each weft yarn, same length; None: zeros."""
    warp_factors: tuple[float, ...] | None = None
    """Per-warp load factors (warps,); None: 1 each."""
    weft_factors: tuple[float, ...] | None = None
    """Per-weft load factors (wefts,); None: 1 each."""
    pullout: int | None = None
    """A pull-out (docs/model.md section 10): warp `pullout` (1-based) has its first node free and
    its last node displaced by `warp_values`; every other warp clamped at both ends, the wefts'
    last nodes displaced by `weft_values` times `weft_factors` (zeros: clamped). Needs
    displacement control on the clamped patch, and something pressing the warp onto the
    wefts (tensioned wefts, or gravity): the as-woven contacts carry no force and a
    translated warp keeps its closures, so alone it slides out at zero force (a rigid-body
    mode)."""
    hold: str = "none"
    """"none", "warp" or "weft": every dof of that family held at its as-woven position
    (a check of docs/model.md section 10: with the wefts held, each warp is the one-yarn model)."""
    tolerance: float = 1e-11
    """Newton's residual tolerance [N] (docs/model.md section 6), or the rounding floor where
    higher."""
    max_iterations: int = 200
    """Newton iterations per solve."""

    def __post_init__(self):
        _check(self)

    @property
    def steps(self) -> int:
        return len(self.warp_values)

    def loads(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """(warp values, weft values) of the load path, weft zeros when not given."""
        weft = self.weft_values if self.weft_values is not None else (0.0,) * self.steps
        return tuple(self.warp_values), tuple(weft)


def _check(spec: FabricSpec) -> None:
    """Refuse what the fabric model does not (yet) cover, naming the field."""
    if spec.warp.segments % (2 * spec.wefts) or spec.weft.segments % (2 * spec.warps):
        raise ValueError("warp.segments must be a multiple of 2 wefts, weft.segments of 2 warps")
    if spec.boundary not in ("clamped", "periodic"):
        raise ValueError(f"boundary must be 'clamped' or 'periodic', not {spec.boundary!r}")
    if spec.planes not in ("fixed", "affine", "cell"):
        raise ValueError(f"planes must be 'fixed', 'affine' or 'cell', not {spec.planes!r}")
    if spec.planes == "cell" and spec.boundary != "periodic":
        raise ValueError("planes 'cell' are a periodic cell's (docs/model.md section 10)")
    if spec.pullout is not None and spec.planes != "fixed":
        raise ValueError("a pull-out keeps the planes fixed (docs/model.md section 10)")
    if spec.boundary == "periodic" and spec.gravity is not None:
        raise ValueError("gravity is refused on the periodic cell (docs/model.md section 10)")
    if spec.boundary == "periodic" and (spec.warps % 2 or spec.wefts % 2):
        raise ValueError("a periodic cell needs an even number of warps and of wefts")
    if spec.control not in ("force", "displacement"):
        raise ValueError(f"control must be 'force' or 'displacement', not {spec.control!r}")
    if spec.hold not in ("none", "warp", "weft"):
        raise ValueError(f"hold must be 'none', 'warp' or 'weft', not {spec.hold!r}")
    if spec.pullout is not None and (spec.control != "displacement" or spec.boundary != "clamped"
                                     or not 1 <= spec.pullout <= spec.warps):
        raise ValueError("pullout names a warp 1..warps, under displacement control on the "
                         "clamped patch")
    if spec.weft_values is not None and len(spec.weft_values) != spec.steps:
        raise ValueError("weft_values must have as many entries as warp_values")
    if not spec.core_stiffness > 0:
        raise ValueError("core_stiffness must be > 0 (inf for none)")
