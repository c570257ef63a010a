"""The model of a scene and its elements: the one data model of every scene (`structure`),
the builders that make it from a scene (`builders`), the element library (`terms`, and the
fabric's in `fabric`), the one-yarn model (`yarn`) with its state, geometry and assembly, the
specimen's layout (`specimen_layout`) and its normalised shear force (`shear_force`), the
prescribed loads (`loading`), the model's domain (`domain`), a load step's start and solution
as models and solvers exchange them (`step`) and what a finished step records
(`observables`).

`from dynfab.model import build_model` keeps working: the names are looked up in `yarn`
on first use."""

import importlib

_PUBLIC = ("build_model", "initial_state", "Model")


def __getattr__(name: str):
    """A public name of the model (`yarn`), imported on first use."""
    if name in _PUBLIC:
        return getattr(importlib.import_module("dynfab.model.yarn"), name)
    raise AttributeError(f"module 'dynfab.model' has no attribute {name!r}")
