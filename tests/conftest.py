"""Shared test fixtures: generic scene building only (no physics, no expected values)."""

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
