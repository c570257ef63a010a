"""Scenes as structures (`dynfab.model.structure`): each model is a builder, and nothing past it
asks which model a scene is."""

from __future__ import annotations

from typing import NamedTuple

from dynfab.scene import Scene, yarn_count
from dynfab.model.structure import Structure


class MeshSize(NamedTuple):
    """A scene's mesh as the run's budget sees it (`dynfab.budget`), from the scene alone,
    before anything is built."""

    nodes: int
    yarns: int
    crossings: int
    coupled: bool
    """Chains tied to one another (a fabric): the static solver factors one sparse Hessian,
    whose fill grows as nodes^1.5; otherwise every chain is its own band."""
    name: str
    """The mesh as a refusal of its memory names it ("a 16 x 16 fabric of 4896 nodes")."""
    short_name: str
    """The mesh as a refusal of its result file names it ("a 4896-node fabric")."""


def mesh_size(scene: Scene) -> MeshSize:
    """The size of a validated scene's mesh. A one-yarn scene's: its yarns' nodes and
    crossings; a fabric's: n_wa warps of N+1 nodes and n_we wefts of M+1 (docs/model.md section
    10); a specimen's from its area A (section 11): A / (p_wa p_we) crossings, each family n
    segments per spacing, so 2 n A / (p_wa p_we) nodes, plus a yarn's end pieces (a bound, not
    a count)."""
    g, weft, s = scene.geometry, scene.weft, scene.specimen
    if s is not None:
        p_wa, p_we = scene.warp.spacing, weft.spacing
        area = s.width * s.height if s.test == "bias_extension" else s.side ** 2
        extent = (s.width + s.height) if s.test == "bias_extension" else 2.0 * s.side
        crossings, yarns = area / (p_wa * p_we), 2.0 * extent / min(p_wa, p_we)
        n = s.segments_per_spacing
        nodes = int(2 * n * crossings + (n + 2) * yarns)
        return MeshSize(nodes, int(yarns), int(crossings), True,
                        f"a {s.test} specimen of {nodes} nodes", f"a {nodes}-node fabric")
    if g.model == "fabric":
        nodes = weft.count * (g.segments + 1) + g.crossings * (weft.segments + 1)
        return MeshSize(nodes, weft.count + g.crossings, weft.count * g.crossings, True,
                        f"a {weft.count} x {g.crossings} fabric of {nodes} nodes",
                        f"a {nodes}-node fabric")
    yarns = yarn_count(scene)
    return MeshSize((g.segments + 1) * yarns, yarns, g.crossings * yarns, False,
                    f"geometry.segments = {g.segments} x {yarns} yarn(s)",
                    f"{g.segments + 1} nodes x {yarns} yarn(s)")


def scene_kind(scene: Scene) -> str:
    """The kind of model a validated scene is: "specimen" (a [specimen] table, docs/model.md
    section 11), "fabric" (section 10) or "yarn" (sections 1-9); a result file's root
    attribute "model" and a measured curve's kind (`dynfab.results.measured_curve.MODELS`)."""
    if getattr(scene, "specimen", None) is not None:
        return "specimen"
    return scene.geometry.model




def build_model(scene: Scene):
    """The model of a validated scene (`scene_kind`): a shear specimen's
    (`dynfab.model.fabric.specimen_model.SpecimenModel`, docs/model.md section 11), a
    fabric's (`dynfab.model.fabric.model.FabricModel`, section 10) or the one-yarn model
    (`dynfab.model.yarn.yarn_model`, sections 1-9)."""
    kind = scene_kind(scene)
    if kind == "specimen":
        from dynfab.model.fabric.specimen_model import SpecimenModel

        return SpecimenModel.from_scene(scene)
    if kind == "fabric":
        from dynfab.model.fabric.model import FabricModel

        return FabricModel.from_scene(scene)
    from dynfab.model.yarn import yarn_model

    return yarn_model(scene)


def build_structure(scene: Scene) -> Structure:
    """The structure of a validated scene: the paper's yarn (docs/model.md sections 1-9) or the
    woven fabric (section 10)."""
    if scene.geometry.model == "fabric":
        from dynfab.model.builders.fabric import fabric_structure

        return fabric_structure(scene)
    from dynfab.model.builders.yarn import yarn_structure

    return yarn_structure(scene)
