"""Memory and result-file estimates made before a run allocates anything, and the refusal
of a scene that cannot fit (one line, exit status 2)."""

import subprocess
import sys
from pathlib import Path

import pytest

import dynfab
from dynfab import budget
from dynfab.model.builders import mesh_size
from independent import PAPER_WARP, PAPER_WEFT, make_scene, scene_toml

def yarn_tables(segments: int, load: dict) -> dict:
    """The paper yarn with 4 crossings, prestressed, `segments` segments, load table `load`."""
    return {"geometry": {"length": 0.1, "segments": segments, "crossings": 4,
                         "amplitude": 0.5e-3, "reference": "prestressed"},
            "warp": PAPER_WARP, "weft": PAPER_WEFT, "load": load}


def scene(segments=64, load=None):
    return make_scene(**yarn_tables(segments, load or {"values": [0.001, 0.002, 0.003]}))


def test_result_file_estimate_bounds_a_real_file(tmp_path):
    """The estimate counts positions, crossing datasets and scalars; HDF5 adds headers and
    the solver a few more datasets: the real file lies within a factor 2 of it."""
    small = scene(segments=4096)
    out = tmp_path / "r.h5"
    dynfab.run(small, solver="static", out=out)
    actual = out.stat().st_size
    assert 0.5 < actual / budget.result_file_bytes(small) < 2.0


def test_memory_estimate_covers_the_measured_peak():
    """Peak resident memory of a real run stays below the estimate. The peak is the child's own
    (VmHWM, its address space's high-water mark), not getrusage's ru_maxrss: Linux carries
    ru_maxrss across exec from the process that spawned it, so under pytest it reported the
    test process's own size (904 MB after the study tests, against 358 MB measured alone)."""
    text = scene_toml(yarn_tables(262144, {"values": [0.001]}))
    code = ("import re, dynfab\n"
            "try:\n"
            f"    dynfab.run(dynfab.parse_scene_text({text!r}), solver='static', max_iterations=3)\n"
            "except dynfab.SolverError:\n"
            "    pass\n"
            "status = open('/proc/self/status').read()\n"
            "print(int(re.search(r'VmHWM:\\s*(\\d+) kB', status).group(1)) * 1024)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert int(done.stdout.split()[-1]) < budget.memory_bytes(scene(segments=262144))


def test_a_mesh_beyond_memory_is_refused_with_the_estimate(monkeypatch):
    monkeypatch.setattr(budget, "available_memory_bytes", lambda: 10**9)
    with pytest.raises(dynfab.UserError, match=r"needs about 2\.\d+ GB of memory .* but 1 GB is available"):
        dynfab.run(scene(segments=2_000_000), solver="static")


def test_a_result_file_beyond_the_free_disk_is_refused(monkeypatch, tmp_path):
    usage = type("usage", (), {"free": 10**5})
    monkeypatch.setattr(budget.shutil, "disk_usage", lambda path: usage)
    out = tmp_path / "big.h5"
    with pytest.raises(dynfab.UserError, match=r"would take about .* but 100 kB is free there"):
        dynfab.run(scene(segments=4096), solver="static", out=out)
    assert not out.exists()


def test_a_huge_load_path_is_refused_before_it_is_built():
    with pytest.raises(dynfab.UserError, match="load.steps = 100000000: at most 10,000,000"):
        scene(load={"max": 0.01, "steps": 100000000})


def fabric_scene(n=4, values=(1e-3, 2e-3), boundary="clamped"):
    """A clamped n x n patch of the paper's yarns (14 segments per half-wave), no friction
    (`boundary` "periodic": the periodic cell of the same yarns)."""
    yarn = {"EA": 13.72, "EI": 1.47e-7, "kawabata_C": 0.2e-3, "kawabata_K": 0.2}
    return make_scene(
        geometry={"model": "fabric", "length": 0.00625 * n, "segments": 14 * n, "crossings": n,
                  "amplitude": 0.5e-3, "boundary": boundary},
        warp=yarn, weft={**yarn, "count": n, "segments": 14 * n, "amplitude": 0.5e-3},
        load={"values": list(values)})


def test_fabric_result_file_estimate_bounds_a_real_file(tmp_path):
    """The fabric's estimate counts both families' nodes, its n_wa x n_we crossing datasets
    and per-yarn scalars: the real file lies within a factor 2 of it, as the one-yarn one."""
    patch = fabric_scene(8)
    out = tmp_path / "f.h5"
    dynfab.run(patch, solver="static", out=out)
    assert 0.5 < out.stat().st_size / budget.result_file_bytes(patch) < 2.0


def test_fabric_memory_estimate_grows_as_its_sparse_factors():
    """nodes^1.5 (module docstring): a 64 x 64 patch of 8 segments per half-wave (65,664
    nodes) is estimated above benchmarks/fabric.json's measured peak of 1.71 GB."""
    yarn = {"EA": 13.72, "EI": 1.47e-7, "kawabata_C": 0.2e-3, "kawabata_K": 0.2}
    patch = make_scene(
        geometry={"model": "fabric", "length": 0.4, "segments": 512, "crossings": 64,
                  "amplitude": 0.5e-3},
        warp=yarn, weft={**yarn, "count": 64, "segments": 512, "amplitude": 0.5e-3},
        load={"values": [1e-3]})
    assert mesh_size(patch).nodes == 65664
    assert budget.memory_bytes(patch) > 1.71e9 * 1.1


def test_a_fabric_beyond_memory_is_refused_with_the_estimate(monkeypatch):
    monkeypatch.setattr(budget, "available_memory_bytes", lambda: 10**9)
    big = fabric_scene(64)
    with pytest.raises(dynfab.UserError, match=r"a 64 x 64 fabric of 114816 nodes needs about "
                                               r".* of memory .* but 1 GB is available"):
        dynfab.run(big, solver="static")


def test_a_shear_specimen_beyond_memory_is_refused_with_the_estimate(monkeypatch):
    """A specimen's nodes are estimated from its area (`dynfab.model.builders.mesh_size`,
    docs/model.md section 11): Cao's 150 x 450 mm bias specimen (20,330 nodes built) is
    estimated at about that, and refused where memory is short, in one line naming the
    specimen."""
    from dynfab.scene import load_scene
    scene = load_scene(Path(__file__).resolve().parents[1] / "runs" / "cao2008_bias_150x450.toml")
    nodes = mesh_size(scene).nodes
    assert 20330 <= nodes <= 1.2 * 20330
    monkeypatch.setattr(budget, "available_memory_bytes", lambda: 10**8)
    with pytest.raises(dynfab.UserError, match=r"^a bias_extension specimen of \d+ nodes needs "
                                               r"about .* but 100 MB is available"):
        dynfab.run(scene, solver="static")


def test_a_fabric_result_file_beyond_the_free_disk_is_refused(monkeypatch, tmp_path):
    usage = type("usage", (), {"free": 10**5})
    monkeypatch.setattr(budget.shutil, "disk_usage", lambda path: usage)
    out = tmp_path / "big.h5"
    with pytest.raises(dynfab.UserError, match=r"would take about .* of a 1808-node fabric\), "
                                               r"but 100 kB is free there"):
        dynfab.run(fabric_scene(8, values=[1e-3] * 50), solver="static", out=out)
    assert not out.exists()


def test_a_periodic_cell_is_estimated_and_refused_as_a_patch(monkeypatch, tmp_path):
    """The periodic cell (geometry.boundary = "periodic": the same nodes and crossings as the
    clamped patch, its cell lengths and planes besides): runs/fabric_biaxial.toml's file lies
    within a factor 2 of its estimate, and a 64 x 64 cell beyond the memory is refused with
    the estimate before anything is built."""
    from pathlib import Path

    cell = dynfab.load_scene(Path(__file__).resolve().parents[1] / "runs" / "fabric_biaxial.toml")
    assert cell.geometry.boundary == "periodic"
    out = tmp_path / "cell.h5"
    dynfab.run(cell, solver="static", out=out)
    assert 0.5 < out.stat().st_size / budget.result_file_bytes(cell) < 2.0
    monkeypatch.setattr(budget, "available_memory_bytes", lambda: 10**9)
    big = fabric_scene(64, boundary="periodic")
    assert big.geometry.boundary == "periodic"
    with pytest.raises(dynfab.UserError, match=r"a 64 x 64 fabric of 114816 nodes needs about "
                                               r".* of memory .* but 1 GB is available"):
        dynfab.run(big, solver="static")
