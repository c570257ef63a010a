"""Shared test fixtures: generic scene building and the choice of sparse factorisation (no
physics, no expected values); and the order the test files are handed to the workers in."""

import pytest

from dynfab.scene import Scene, parse_scene_text
from independent import scene_toml


@pytest.fixture(scope="session")
def make_scene():
    """Factory: make_scene(geometry={...}, warp={...}, load={...}, ...) -> a parsed Scene.

    Goes through `parse_scene_text`, so every scene a test builds is validated
    exactly as a user's scene file would be.
    """
    def make(**tables) -> Scene:
        return parse_scene_text(scene_toml(tables))
    return make


@pytest.fixture(params=["superlu", "pardiso"])
def factoriser(request, monkeypatch):
    """The fabric's symmetric factorisation (`dynfab.model.fabric.ordering.symmetric_factor`):
    SuperLU alone, or PARDISO first at every size (skipped where MKL is not installed)."""
    from dynfab.linalg import pardiso
    if request.param == "pardiso" and not pardiso.available():
        pytest.skip("MKL (PARDISO) is not installed (wheels for x86-64 Linux and Windows only)")
    if request.param == "superlu":
        monkeypatch.setattr(pardiso, "available", lambda: False)
    else:
        monkeypatch.setattr(pardiso, "MIN_UNKNOWNS", 0)  # the tests' matrices are small
    return request.param


@pytest.fixture
def superlu_alone(monkeypatch):
    """The fabric's symmetric factorisations by SuperLU alone (PARDISO off)."""
    from dynfab.linalg import pardiso
    monkeypatch.setattr(pardiso, "available", lambda: False)


LONGEST_FILES = ("test_node_terms.py", "test_sliding_crossings.py", "test_shear_transient.py",
                 "test_cli.py", "test_onset.py", "test_study.py", "test_study_cluster.py",
                 "test_fabric_onset.py", "test_registry.py", "test_shear_dynamic.py",
                 "test_fit.py")
"""The eleven test files that take longest, longest first (`pytest --durations=0` summed per
file, 2026-12-07: 215 s down to 41 s; docs/results.md, "The test files' order").
Handed out first to the workers (pyproject.toml's addopts: one file per worker at a time,
in collection order), a long file cannot start last and leave the other core idle."""


def pytest_collection_modifyitems(items):
    """The longest files first (LONGEST_FILES), the others after them in their own order."""
    rank = {name: k for k, name in enumerate(LONGEST_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
