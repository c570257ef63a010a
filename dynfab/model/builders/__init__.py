"""Scenes as structures (`dynfab.model.structure`): each model is a builder, and nothing past it
asks which model a scene is."""

from __future__ import annotations

from dynfab.scene import Scene
from dynfab.model.structure import Structure


def build_model(scene: Scene):
    """The model of a validated scene: a shear specimen's
    (`dynfab.model.fabric.specimen_model.SpecimenModel`, docs/model.md section 11), a
    fabric's (`dynfab.model.fabric.model.FabricModel`, section 10) or the one-yarn model
    (`dynfab.model.yarn.yarn_model`, sections 1-9): the one place that asks which."""
    if getattr(scene, "specimen", None) is not None:
        from dynfab.model.fabric.specimen_model import SpecimenModel

        return SpecimenModel.from_scene(scene)
    if scene.geometry.model == "fabric":
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
