"""TOML text of a scene given as plain Python values, for the tests that write scene files
(valid or deliberately wrong) before any Scene exists; `dynfab.scene.scene_to_toml` writes a
parsed Scene back. Light: json, math and numpy only, so tests/test_scene.py stays fast.
"""

from __future__ import annotations

import json
import math

import numpy as np


def toml_value(value) -> str:
    """One TOML value: bool, number (numpy's too; nan and +-inf as TOML spells them),
    string, list/tuple/array, or a dict as an inline table."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + "}"
    return repr(value)


def toml_key(key: str) -> str:
    """A bare key, or a quoted one where it has a dot (a [sweep] key such as "warp.EA")."""
    return json.dumps(key) if "." in key else key


def toml_text(scene: dict) -> str:
    """{key: value, table: {key: value}} as TOML: the top-level values first, then one
    [table] per dict, each followed by a blank line."""
    lines = [f"{toml_key(k)} = {toml_value(v)}" for k, v in scene.items()
             if not isinstance(v, dict)]
    for name, table in scene.items():
        if isinstance(table, dict):
            lines.append(f"[{name}]")
            lines += [f"{toml_key(k)} = {toml_value(v)}" for k, v in table.items()]
            lines.append("")
    return "\n".join(lines) + "\n"
