"""Every public name of the package resolves: `dynfab/__init__.py` imports them lazily from their
homes (`_HOMES`), so a name whose module moved would raise only when a user's script first
used it (build_model once did, after it moved to `dynfab.model.builders`)."""

import importlib

import dynfab


def test_every_public_name_resolves_to_the_object_its_home_defines():
    for name in dynfab.__all__:
        value = getattr(dynfab, name)
        assert value is not None, name
        home = dynfab._HOMES.get(name)
        if home is not None:
            assert value is getattr(importlib.import_module(home), name), name
