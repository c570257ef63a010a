"""The model of a scene and its elements: the one data model of every scene (`structure`),
the builders that make it from a scene (`builders`), the element library (`terms`, and the
fabric's in `fabric`), the one-yarn model (`yarn`) with its state, geometry and assembly, the
specimen's layout (`specimen_layout`) and its normalised shear force (`shear_force`), the
prescribed loads (`loading`), the model's domain (`domain`), a load step's start and solution
as models and solvers exchange them (`step`) and what a finished step records
(`observables`).

`from dynfab.model import build_model` (`builders`), `initial_state` and `Model` (`yarn`):
looked up on first use."""

import importlib

_PUBLIC = {"build_model": "dynfab.model.builders", "initial_state": "dynfab.model.yarn",
           "Model": "dynfab.model.yarn"}


def __getattr__(name: str):
    """A public name of the model, imported on first use."""
    if name in _PUBLIC:
        return getattr(importlib.import_module(_PUBLIC[name]), name)
    raise AttributeError(f"module 'dynfab.model' has no attribute {name!r}")
