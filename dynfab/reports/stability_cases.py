"""The stability study's vocabulary: the methods it compares, its cases and plans (full and
quick), and how a number is shown in its table.

The study (`dynfab.reports.stability`), its map (`stability_plots`) and its table
(`stability_tables`) all import these names from here.
"""

from __future__ import annotations

from dataclasses import dataclass

from dynfab.scene import Dynamic

METHODS = {
    "kinetic": Dynamic(damping="kinetic"),
    "viscous": Dynamic(damping="viscous"),
    "fire": Dynamic(damping="fire"),
    "semi_implicit": Dynamic(method="semi_implicit"),
}
"""The methods compared: explicit (fictitious masses) with each damping, and semi_implicit."""
EXPLICIT = ("kinetic", "viscous", "fire")

QUICK_METHODS = {("displacement", False): ("kinetic", "viscous", "fire", "semi_implicit"),
                 ("displacement", True): ("kinetic", "semi_implicit")}
"""--quick: (control, friction) -> the methods whose kernel variants the dynamic tests
compile (test_dynamic_relaxation, test_dynamic_semi_implicit), so that the quick report
compiles nothing new. The undamped (viscous c = 0) variant of the bisection is the
frictionless one; with friction the quick bisection uses kinetic damping instead, which
measures the linear instability only (`dynfab.reports.stability.measure_stable_dt`)."""

FRICTION_PATH = (0.0025, 0.005, 0.0075, 0.01, 0.0075, 0.005, 0.0025, 0.0, 0.0025, 0.005)
"""End forces [N] of the friction path cases: loading, unloading to zero, reloading."""


@dataclass(frozen=True)
class Case:
    """One stiff or extreme variant of the paper yarn, solved as one load step."""

    name: str
    """Short unique id (a row of the table)."""
    family: str
    """"baseline", "kawabata", "stretch", "mesh", "weft", "load", "friction" or "reference"."""
    label: str
    """What is extreme about it, for the table."""
    changes: tuple = ()
    """(key, value) pairs applied to the paper yarn; see `dynfab.reports.stability.case_scene` for the keys."""
    friction: bool = False
    """Gralen friction (paper_fig5.toml entry 0) on."""
    control: str = "displacement"
    strain: float = 0.01
    """End displacement / L [-]; under force control P is the static reaction at that
    displacement (of the same yarn under displacement control)."""


@dataclass(frozen=True)
class PathCase:
    """The friction yarn (paper_fig5.toml entry 0) driven through a load path, unloading
    included: the stick/slip reversals a single load step never meets."""

    name: str
    segments: int
    """N of this case (any multiple of 2 x crossings)."""
    values: tuple = FRICTION_PATH
    """Applied end forces [N] (force control), one load step each."""
    control: str = "force"
    """"force"; "displacement": the dynamic methods follow the static reference's end
    displacements along the force path (--quick: the variants the tests compile)."""


@dataclass(frozen=True)
class Plan:
    """The yarn's size and the cases of a full or quick report."""

    name: str
    crossings: int
    """Crossings of the yarn: the paper's 16, or fewer at the same spacing."""
    segments: int
    """N at the paper's mesh density."""
    cases: tuple[Case, ...]
    paths: tuple[PathCase, ...] = ()


def _kawabata(value: float) -> str:
    return f"{value:g}"


FULL_CASES = (
    Case("baseline", "baseline", "paper yarn, K = 0.2 m/N, u = 1 % of L"),
    *(Case(f"K={_kawabata(k)}", "kawabata", f"Kawabata K = {k:g} m/N (both yarns)",
           (("kawabata_K", k),)) for k in (1e-4, 1e-3, 1e-2, 1.0, 10.0)),
    Case("C=2e-6", "kawabata", "Kawabata C = 2e-6 m (1 % of the paper's), K = 2 m/N: "
         "the compression saturates", (("kawabata_C", 2e-6), ("kawabata_K", 2.0))),
    Case("EAx1000", "stretch", "EA x 1000", (("EA_factor", 1000.0),)),
    *(Case(f"N={n}", "mesh", f"N = {n} segments", (("geometry.segments", n),))
      for n in (448, 896, 1792, 3584)),
    Case("k_we x1000", "weft", "weft tension P_we making k_we 1000 x stiffer",
         (("k_we_factor", 1000.0),)),
    Case("alpha_we=-0.99", "weft", "compressive weft tension, alpha_we = -0.99 (short of "
         "buckling)", (("alpha_we", -0.99),)),
    Case("alpha_we=-1", "weft", "weft tension at the buckling load, alpha_we = -1",
         (("alpha_we", -1.0),)),
    Case("alpha_we=-1.01", "weft", "weft tension beyond buckling, alpha_we = -1.01",
         (("alpha_we", -1.01),)),
    Case("u=10%", "load", "displacement control, u = 10 % of L", strain=0.10),
    Case("u=50%", "load", "displacement control, u = 50 % of L", strain=0.50),
    *(Case(f"P({round(100 * e)}%)", "load", f"force control, P = the reaction at "
           f"u = {100 * e:g} % of L", control="force", strain=e) for e in (0.01, 0.10, 0.50)),
    *(Case(f"alpha={a:g}, k_t x{f:g}", "friction", f"friction alpha = {a:g}, "
           f"k_t = {f:g} x EA/(L/N)", (("friction.alpha", a), ("stick_factor", f)), friction=True)
      for f in (1.0, 1000.0) for a in (0.0, 0.2, 2.0)),
    Case("as_woven", "reference", "as-woven reference state", (("geometry.reference",
                                                                "as_woven"),)),
    Case("as_woven, alpha=0.2", "reference", "as-woven reference, friction alpha = 0.2",
         (("geometry.reference", "as_woven"),), friction=True),
    Case("as_woven, alpha=2, k_t x1000", "reference", "as-woven reference, friction "
         "alpha = 2, k_t = 1000 x EA/(L/N)", (("geometry.reference", "as_woven"),
                                              ("friction.alpha", 2.0), ("stick_factor", 1000.0)),
         friction=True),
)


QUICK_CASES = (
    Case("K=1e-4", "kawabata", "Kawabata K = 1e-4 m/N (both yarns)", (("kawabata_K", 1e-4),)),
    Case("EAx1000", "stretch", "EA x 1000", (("EA_factor", 1000.0),)),
    Case("alpha_we=-1.01", "weft", "weft tension beyond buckling, alpha_we = -1.01",
         (("alpha_we", -1.01),)),
    Case("u=50%", "load", "displacement control, u = 50 % of L", strain=0.50),
    Case("alpha=2, k_t x1000", "friction", "friction alpha = 2, k_t = 1000 x EA/(L/N)",
         (("friction.alpha", 2.0), ("stick_factor", 1000.0)), friction=True),
)


FULL = Plan(name="full", crossings=16, segments=224, cases=FULL_CASES,
            paths=tuple(PathCase(f"friction path, N={n}", n) for n in (224, 1792, 3584)))


QUICK = Plan(name="quick", crossings=4, segments=56, cases=QUICK_CASES,
             paths=(PathCase("friction path, N=56", 56, control="displacement"),))


def short_number(value, digits: int = 2) -> str:
    """A number for the table; '-' for None."""
    return "-" if value is None else f"{value:.{digits}g}"
