"""Shared test fixtures: generic scene building only (no physics, no expected values)."""

import json

import pytest

from dynfab.scene import Scene, parse_scene_text


def _toml_value(value) -> str:
    """A number, string, bool or list of them as TOML."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


def scene_toml(tables: dict) -> str:
    """TOML text of a scene given as {table: {key: value}} (flat tables only)."""
    lines = []
    for name, table in tables.items():
        lines.append(f"[{name}]")
        lines.extend(f"{key} = {_toml_value(value)}" for key, value in table.items())
        lines.append("")
    return "\n".join(lines)


@pytest.fixture(scope="session")
def make_scene():
    """Factory: make_scene(geometry={...}, warp={...}, load={...}, ...) -> a parsed Scene.

    Goes through `parse_scene_text`, so every scene a test builds is validated
    exactly as a user's scene file would be.
    """
    def make(**tables) -> Scene:
        return parse_scene_text(scene_toml(tables))
    return make
