"""A measured curve drawn over a run's figures (`dynfab plot --data`): the CSV read as
`dynfab fit --data` reads it (`dynfab.results.measured_curve`), as points of the quantities the
figures draw (`measured_points`), and drawn (`draw_measured`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dynfab.results.file import Results


@dataclass(frozen=True)
class Measured:
    """A measured curve as the figures draw it: the file's name, and per quantity its points
    in SI units (`measured_points`)."""

    label: str
    end_displacement: np.ndarray | None = None
    """[m] (a yarn's, or a specimen's clamp displacement d)."""
    end_force: np.ndarray | None = None
    """[N] (a yarn's end force, or a specimen's clamp force)."""
    strain: np.ndarray | None = None
    """The warps' nominal strain [-] (a fabric)."""
    stress: np.ndarray | None = None
    """The warps' load per unit width [N/m] (a fabric)."""


def measured_points(results: Results, data) -> Measured:
    """The CSV curve `data` read as `dynfab fit --data` reads it for the file's scene (its
    model and control; the first error names the columns expected and found), as points of
    the quantities the figures draw."""
    from dynfab.results.measured_curve import model_kind, read_curve
    from dynfab.scene import parse_scene_text

    scene = parse_scene_text(results.attrs["scene"])
    model, control = model_kind(scene), results.attrs.get("load_control", "force")
    curve = read_curve(data, control, model)
    found = dict(curve.measured, **{("end_displacement" if control == "displacement"
                                     else "load"): curve.load})
    label = f"measured: {Path(data).stem}"
    if model == "specimen":
        return Measured(label, end_displacement=curve.load, end_force=found["clamp_force"])
    if model == "fabric":
        strain = found.get("warp_strain")
        if strain is None and control == "displacement":
            strain = curve.load / float(results.attrs["projected_length"])
        stress = found.get("warp_stress")
        if stress is None and control == "force":
            stress = curve.load / (float(results.attrs["weft_length"])
                                   / float(scene.weft.count))
        return Measured(label, strain=strain, stress=stress)
    return Measured(label, end_displacement=found.get("end_displacement"),
                    end_force=found.get("end_force", found.get("load")))


def draw_measured(ax, x, y, measured: Measured) -> None:
    """The measured points on `ax` (x, y already in the axis' units), where both exist."""
    if x is not None and y is not None:
        ax.plot(x, y, linestyle="none", marker="D", ms=4, mfc="none", color="k",
                label=measured.label)
