"""Scenes as structures (`dynfab.model.structure`): each model is a builder, and nothing past it
asks which model a scene is."""

from __future__ import annotations

from dynfab.scene import Scene
from dynfab.model.structure import Structure


def build_structure(scene: Scene) -> Structure:
    """The structure of a validated scene: the paper's yarn (docs/model.md sections 1-9) or the
    woven fabric (section 10)."""
    if scene.geometry.model == "fabric":
        from dynfab.model.builders.fabric import fabric_structure

        return fabric_structure(scene)
    from dynfab.model.builders.yarn import yarn_structure

    return yarn_structure(scene)
