"""What `dynfab.run` does around the solver's step is done once per process, per scene or per
table, not once per run: a fit or a study runs thousands of small scenes
(benchmarks/run_overhead.py times it). Each saving keeps the results as they were:

- the installed version is looked up once per process;
- a scene is validated once (the very same frozen object passed again is not re-checked),
  and a scene changed in any way is checked again;
- `scene_to_toml` writes each table once while the table lives: a `with_key` scene, which
  shares every table but the one changed, has only that one written anew, to the text
  written from scratch;
- the available memory is read at most once per `MEMORY_READING_AGE`;
- a run's yarn labels are made only when a yarn has folded (the message names it).

No timing here: the counts of the costly calls are what is checked.
"""

import importlib.metadata
from dataclasses import replace

import numpy as np
import pytest

import dynfab
from dynfab import budget, scene as scene_module
from dynfab.model.domain import check_not_folded
from dynfab.errors import SolverError, UserError
from dynfab.scene import scene_to_toml, validate_scene, with_key
from independent import PAPER_FRICTION, PAPER_WARP, PAPER_WEFT, make_scene


def small_scene():
    """The paper's yarn over 4 crossings, 16 segments, friction on, one force step."""
    return make_scene(geometry={"length": 0.025, "segments": 16, "crossings": 4,
                                "amplitude": 0.5e-3, "reference": "prestressed"},
                      warp=PAPER_WARP, weft=PAPER_WEFT, friction=PAPER_FRICTION,
                      load={"control": "force", "values": [0.05]})


def counting(monkeypatch, owner, name):
    """Replace owner.name by a wrapper that counts its calls; the list of calls' arguments."""
    calls, original = [], getattr(owner, name)

    def counted(*args, **kwargs):
        calls.append(args)
        return original(*args, **kwargs)

    monkeypatch.setattr(owner, name, counted)
    return calls


def test_the_version_is_looked_up_once_per_process(monkeypatch):
    scene = small_scene()
    calls = counting(monkeypatch, importlib.metadata, "version")
    first = dynfab.run(scene, solver="static")
    second = dynfab.run(scene, solver="static")
    assert len(calls) <= 1
    assert first.attrs["dynfab_version"] == second.attrs["dynfab_version"]


def test_a_scene_is_validated_once_and_a_changed_one_again(monkeypatch):
    scene = small_scene()  # validated by the parser
    checks = counting(monkeypatch, scene_module, "_check_scene")
    assert validate_scene(scene) is scene
    dynfab.run(scene, solver="static")
    assert checks == []
    # a copy with a bad value is a new object: checked, and refused
    bad = replace(scene, geometry=replace(scene.geometry, segments=7))
    with pytest.raises(UserError, match="geometry.segments"):
        dynfab.run(bad, solver="static")
    assert len(checks) == 1
    # a run option makes a new scene, checked once
    dynfab.run(scene, solver="static", tolerance=1e-10)
    assert len(checks) == 2


def test_scene_text_is_written_once_per_table_and_stays_exact(monkeypatch):
    scene = small_scene()
    scene_to_toml(scene)  # every table written (and kept while it lives)
    values = counting(monkeypatch, scene_module, "_toml_value")
    changed = with_key(scene, "warp.EA", 10.0)
    text = scene_to_toml(changed)
    # title (none here) and the [warp] table's values only: the others are shared tables
    assert len(values) == len([v for v in vars(changed.warp).values() if v is not None])
    assert "EA = 10.0" in text and "EA = 13.72" in scene_to_toml(scene)
    # the same text as written from scratch, and it reads back to the same scene
    monkeypatch.setattr(scene_module, "_TABLE_LINES", {})
    assert scene_to_toml(changed) == text
    assert dynfab.parse_scene_text(text).warp == changed.warp


def test_the_available_memory_is_read_once_per_reading_age(monkeypatch):
    clock = [1000.0]
    monkeypatch.setattr(budget.time, "monotonic", lambda: clock[0])
    monkeypatch.setattr(budget, "_last_reading", None)
    reads = counting(monkeypatch, budget, "_read_available_memory")
    scene = small_scene()
    for _ in range(3):
        budget.check_budget(scene, None)
    assert len(reads) == 1
    clock[0] += 1.01 * budget.MEMORY_READING_AGE
    budget.check_budget(scene, None)
    assert len(reads) == 2


def test_yarn_labels_are_made_only_for_a_folded_yarn():
    made = []

    def labels():
        made.append(1)
        return ["yarn 1", "yarn 2"]

    straight = np.stack([np.linspace(0.0, 1.0, 5), np.zeros(5)], axis=-1)
    check_not_folded([np.stack([straight, straight])], labels)
    assert made == []
    folded = straight.copy()
    folded[3, 0] = 0.1
    with pytest.raises(SolverError, match="yarn 2 folded back at segment 3"):
        check_not_folded([np.stack([straight, folded])], labels)
    assert made == [1]
