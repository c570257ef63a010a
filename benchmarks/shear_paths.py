"""The Cao scenes' paths as a researcher reads them (docs/results.md, "The woven-in contact"):
for each result file of an in-plane shear specimen, how far its path ran (d reached, of the
scene's last d), the clamp force [N] and the normalised shear force [N/m] at nominal 5, 10,
20, 30 and 40 degrees (linear in the nominal angle between the finished steps; '-' past the
last one), and after step 0 the median contact force over the preload, by the crossings'
rank from a free yarn end (`dynfab.model.builders.woven_rest.crossings_from_free_end`). The
normalised force is computed from the clamp force by today's `dynfab.model.shear_force`, so files
of different trees compare on one normalisation.

Run: PYTHONPATH=. python benchmarks/shear_paths.py FILE.h5 [FILE.h5 ...] [--label NAME]
     [--out benchmarks/shear_paths.json]
(the files from `dynfab run runs/cao2008_<scene>.toml --out FILE.h5`; prints a table per
file, writes the JSON)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from dynfab.results.file import read_results  # noqa: E402
from dynfab.scene import parse_scene_text  # noqa: E402
from dynfab.model.shear_force import (  # noqa: E402
    bias_normalised_shear_force, frame_normalised_shear_force)
from dynfab.plots.specimen import nominal_angles  # noqa: E402

OUTPUT = Path(__file__).resolve().parent / "shear_paths.json"
ANGLES_DEG = (5.0, 10.0, 20.0, 30.0, 40.0)
RANKS = (1, 2, 3, 4)
"""Ranks from a free yarn end reported one by one; the rest as 'interior'."""


def _at_angles(angle: np.ndarray, values: np.ndarray) -> list:
    """values interpolated at ANGLES_DEG on the loaded steps (None past the last)."""
    loaded = angle > 0.0
    return [float(np.interp(a, angle[loaded], values[loaded])) if a <= angle[loaded].max()
            else None for a in ANGLES_DEG]


def _normalised(results, d: np.ndarray) -> np.ndarray:
    """The normalised shear force [N/m] of every step from its clamp force, by today's
    `dynfab.model.shear_force` (a file written before a change of the normalisation is read as
    today's would write it)."""
    a, force = results.attrs, np.asarray(results.steps["clamp_force"], float)
    if a["specimen_test"] == "bias_extension":
        return bias_normalised_shear_force(d, force, float(a["specimen_width"]),
                                           float(a["specimen_height"]))
    side, fabric = float(a["specimen_side"]), float(a["fabric_side"])
    return np.array([frame_normalised_shear_force(f, side, fabric, x) for f, x in zip(force, d)])


def _band(results) -> dict:
    """Median R / R_p after step 0, by rank from a free yarn end, and over all crossings."""
    preload = float(results.attrs.get("preload", np.nan))
    ratio = np.asarray(results.steps["contact_force"], float)[0] / preload
    out = {"all": float(np.median(ratio))}
    if "free_end_rank" in results.reference:
        rank = np.asarray(results.reference["free_end_rank"])
        for k in RANKS:
            if np.any(rank == k):
                out[str(k)] = float(np.median(ratio[rank == k]))
        out["interior"] = float(np.median(ratio[rank > RANKS[-1]]))
    return {"preload_N": preload, "median_contact_over_preload": out}


def path_of(path: Path) -> dict:
    """One file's figures (module docstring)."""
    results = read_results(path)
    steps = results.steps
    d = np.asarray(steps["load"], float)[:, 0]
    scene = parse_scene_text(results.attrs["scene"])
    angle = np.degrees(nominal_angles(results, d))
    return {"file": str(path), "title": scene.title, "d_reached_m": float(d[-1]),
            "d_last_m": float(scene.load.values[-1]), "steps_finished": int(d.size),
            "steps_in_scene": 1 + len(scene.load.values),
            "nominal_deg": list(ANGLES_DEG),
            "clamp_force_N": _at_angles(angle, np.asarray(steps["clamp_force"], float)),
            "normalised_shear_force_N_per_m": _at_angles(angle, _normalised(results, d)),
            "clamp_force_step0_N": float(steps["clamp_force"][0]), **_band(results)}


def _show(values) -> str:
    return " / ".join("-" if v is None else f"{v:.4g}" for v in values)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", type=Path)
    parser.add_argument("--label", default="", help="what these files are (before, after, ...)")
    parser.add_argument("--out", type=Path, default=OUTPUT)
    args = parser.parse_args()
    rows = [path_of(f) for f in args.files]
    for r in rows:
        print(f"{r['file']}: {r['title']}")
        print(f"  d reached {1e3 * r['d_reached_m']:.4g} of {1e3 * r['d_last_m']:.4g} mm "
              f"({r['steps_finished']} of {r['steps_in_scene']} steps, step 0 included)")
        print(f"  at nominal {_show(r['nominal_deg'])} deg: clamp force "
              f"{_show(r['clamp_force_N'])} N; normalised shear force "
              f"{_show(r['normalised_shear_force_N_per_m'])} N/m")
        print(f"  step 0: clamp force {r['clamp_force_step0_N']:.4g} N; median contact over "
              f"the preload ({r['preload_N']:g} N): " + ", ".join(
                  f"{k} {v:.3f}" for k, v in r["median_contact_over_preload"].items()))
    args.out.write_text(json.dumps({"label": args.label, "files": rows}, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
