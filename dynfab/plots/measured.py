"""A measured curve drawn over a run's figures (`dynfab plot --data`): the CSV read as
`dynfab fit --data` reads it (`dynfab.results.measured_curve`), as points of the quantities the
figures draw (`measured_points`), and drawn (`draw_measured`)."""

from __future__ import annotations

from dataclasses import dataclass, replace
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
    from dynfab.model.builders import scene_kind
    from dynfab.results.measured_curve import read_curve
    from dynfab.scene import parse_scene_text

    scene = parse_scene_text(results.attrs["scene"])
    model, control = scene_kind(scene), results.attrs.get("load_control", "force")
    curve = read_curve(data, control, model)
    found = dict(curve.measured, **{("end_displacement" if control == "displacement"
                                     else "load"): curve.load})
    label = f"measured: {Path(data).stem}"
    return POINTS[model](Measured(label), found, results, scene, control)


def _specimen_points(measured: Measured, found: dict, results: Results, scene, control: str):
    """A specimen's curve: the clamp force against its displacement d."""
    return replace(measured, end_displacement=found["end_displacement"],
                   end_force=found["clamp_force"])


def _fabric_points(measured: Measured, found: dict, results: Results, scene, control: str):
    """A fabric's curve: the warps' strain and load per unit width, the prescribed one from the
    load path (a displacement over the projected length, a force over the width per warp)."""
    strain, stress = found.get("warp_strain"), found.get("warp_stress")
    if strain is None and control == "displacement":
        strain = found["end_displacement"] / float(results.attrs["projected_length"])
    if stress is None and control == "force":
        width = float(results.attrs["weft_length"]) / float(scene.weft.count)
        stress = found["load"] / width
    return replace(measured, strain=strain, stress=stress)


def _yarn_points(measured: Measured, found: dict, results: Results, scene, control: str):
    """A yarn's curve: its end force against its end displacement."""
    return replace(measured, end_displacement=found.get("end_displacement"),
                   end_force=found.get("end_force", found.get("load")))


POINTS = {"yarn": _yarn_points, "fabric": _fabric_points, "specimen": _specimen_points}
"""Each kind of scene's measured curve as the figures' quantities (`measured_points`)."""


def draw_measured(ax, x, y, measured: Measured) -> None:
    """The measured points on `ax` (x, y already in the axis' units), where both exist."""
    if x is not None and y is not None:
        ax.plot(x, y, linestyle="none", marker="D", ms=4, mfc="none", color="k",
                label=measured.label)
