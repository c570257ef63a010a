"""The view of a result file (`dynfab.results.xdmf`, `dynfab.results.views`), read back as its users
read it: with plain meshio (``meshio.xdmf.TimeSeriesReader``, no subclass) and with VTK's XDMF
reader (``vtkXdmfReader``, ParaView's "XDMF Reader"), each compared with the HDF5 file
read by h5py. Expected values come from the HDF5 datasets and from the scene (plane
spacing), never from dynfab.results.xdmf or dynfab.results.views.
"""

import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import meshio
import numpy as np
import pytest
from independent import PAPER_FRICTION, PAPER_WARP, PAPER_WEFT, make_scene, pullout_text
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkCommonCore import vtkOutputWindow, vtkStringOutputWindow
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline
from vtkmodules.vtkIOXdmf2 import vtkXdmfReader

import dynfab
from dynfab.results.file import ResultFile, finished_counts, units_of
from dynfab.run import run_to_file

VTK_POLY_LINE = 4
"""VTK's cell type of an XDMF Polyline (here of 2 nodes: one segment)."""


def read_meshio(view: Path) -> dict:
    """The view as plain meshio reads a time series: the mesh (as-woven points, cells) and
    each step's (time, point data, cell data)."""
    with meshio.xdmf.TimeSeriesReader(view) as reader:
        points, cells = reader.read_points_cells()
        steps = [reader.read_data(k) for k in range(reader.num_steps)]
    return {"points": points, "cells": cells, "steps": steps}


def _vtk_grid(grid) -> dict:
    """Points, segments (node pairs), cell types, point and cell data of a VTK grid."""
    cells = grid.GetCells()
    assert set(np.diff(vtk_to_numpy(cells.GetOffsetsArray()))) <= {2}
    data = {}
    for arrays in (grid.GetPointData(), grid.GetCellData()):
        data.update({arrays.GetArrayName(i): vtk_to_numpy(arrays.GetArray(i))
                     for i in range(arrays.GetNumberOfArrays())})
    return {"points": vtk_to_numpy(grid.GetPoints().GetData()),
            "segments": vtk_to_numpy(cells.GetConnectivityArray()).reshape(-1, 2),
            "types": {grid.GetCellType(i) for i in range(grid.GetNumberOfCells())}, "data": data}


def read_vtk(view: Path) -> dict:
    """The view as ParaView's "XDMF Reader" (VTK) reads it: its time values, the as-woven
    block and the step block at every time. VTK must report no error or warning (ParaView
    shows them to the user; HyperSlab geometry made one per step)."""
    window, previous = vtkStringOutputWindow(), vtkOutputWindow.GetInstance()
    vtkOutputWindow.SetInstance(window)
    try:
        reader = vtkXdmfReader()
        reader.SetFileName(str(view))
        reader.UpdateInformation()
        info = reader.GetOutputInformation(0)
        times = list(info.Get(vtkStreamingDemandDrivenPipeline.TIME_STEPS()) or [])
        steps = []
        for value in times:
            reader.UpdateTimeStep(value)
            steps.append(_vtk_grid(reader.GetOutputDataObject(0).GetBlock(1)))
        reader.Update()
        blocks = reader.GetOutputDataObject(0)
    finally:
        vtkOutputWindow.SetInstance(previous)
    assert window.GetOutput() == ""
    assert blocks.GetNumberOfBlocks() == 2  # the as-woven grid, the steps
    return {"times": times, "as_woven": _vtk_grid(blocks.GetBlock(0)), "steps": steps}


def chains(sizes) -> np.ndarray:
    """The segments of yarns numbered one after the other: (yarns, nodes) per family."""
    pairs, first = [], 0
    for yarns, nodes in sizes:
        for _ in range(yarns):
            pairs += [(first + i, first + i + 1) for i in range(nodes - 1)]
            first += nodes
    return np.array(pairs)


def check_both(view: Path, expected: dict) -> int:
    """Compare the view, read with meshio and with VTK, with `expected` (HDF5 data): ``as_woven``
    (P, 3) points, ``segments`` and ``yarn`` per segment, ``times``, and per step ``points`` and
    the point data by name (``plane``, ``contact_force``, ``slip``; the names the view must
    have; ``atol`` by name where the test recomputes one with other roundings); returns the
    number of steps. Every other value is a copy of a file number (or the scene's plane), so
    those comparisons are exact."""
    mesh, vtk = read_meshio(view), read_vtk(view)
    count = len(expected["times"])
    np.testing.assert_array_equal(mesh["points"], expected["as_woven"])
    assert [block.type for block in mesh["cells"]] == ["line"]
    np.testing.assert_array_equal(mesh["cells"][0].data, expected["segments"])
    np.testing.assert_array_equal(vtk["as_woven"]["points"], expected["as_woven"])
    np.testing.assert_array_equal(vtk["as_woven"]["segments"], expected["segments"])
    np.testing.assert_array_equal(vtk["as_woven"]["data"]["plane"], expected["as_woven_plane"])
    assert len(mesh["steps"]) == len(vtk["steps"]) == count
    np.testing.assert_array_equal(vtk["times"], expected["times"])
    for k in range(count):
        time, point_data, cell_data = mesh["steps"][k]
        grid = vtk["steps"][k]
        assert time == expected["times"][k]
        assert grid["types"] == {VTK_POLY_LINE}
        np.testing.assert_array_equal(grid["segments"], expected["segments"])
        np.testing.assert_array_equal(cell_data["yarn"][0], expected["yarn"])
        np.testing.assert_array_equal(grid["data"]["yarn"], expected["yarn"])
        np.testing.assert_array_equal(point_data["position"], expected["points"][k])
        np.testing.assert_array_equal(grid["points"], expected["points"][k])
        np.testing.assert_array_equal(grid["data"]["position"], expected["points"][k])
        for name, values in expected["point_data"].items():
            atol = expected.get("atol", {}).get(name, 0)
            np.testing.assert_allclose(point_data[name], values[k], rtol=0, atol=atol, err_msg=name)
            np.testing.assert_allclose(grid["data"][name], values[k], rtol=0, atol=atol,
                                       err_msg=name)
        names = {"position", "yarn", *expected["point_data"]}
        assert set(point_data) | set(cell_data) == set(grid["data"]) == names
    return count


def scene(values, yarns=2, **geometry):
    """N = 32, 4 crossings, two adjacent warps with friction (docs/model.md sections 1, 4): a fast
    static run."""
    return make_scene(
        geometry={"length": 0.025, "segments": 32, "crossings": 4, "amplitude": 0.5e-3,
                  "reference": "prestressed", "yarns": yarns, **geometry},
        warp=PAPER_WARP, weft=dict(PAPER_WEFT, length=0.012, count=4), friction=PAPER_FRICTION,
        load={"control": "force", "values": list(values)})


LOADS = [0.05, 0.1, 0.15, 0.2]


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    out = tmp_path_factory.mktemp("xdmf") / "two_yarns.h5"
    run_to_file(scene(LOADS), "static", out)
    return out


def to_3d(positions, planes):
    """(yarns, N+1, 2) positions (x, z) and the plane y of each yarn -> (yarns (N+1), 3)."""
    yarns, nodes, _ = positions.shape
    y = np.repeat(planes, nodes)
    return np.column_stack([positions[..., 0].ravel(), y, positions[..., 1].ravel()])


def expected_times(loads) -> np.ndarray:
    """Each grid's Time: the step's load where the loads strictly increase (ParaView shows the
    load as its time), else the step number (a cycle: ParaView orders grids by time)."""
    loads = np.asarray(loads, float)
    return loads if np.all(np.diff(loads) > 0) else np.arange(1, loads.size + 1, dtype=float)


def test_a_view_s_time_is_the_load_and_a_cycle_s_the_step_number():
    from dynfab.results.xdmf import step_times
    np.testing.assert_array_equal(step_times(np.array([0.0, 1e-3, 2e-3])), [0.0, 1e-3, 2e-3])
    np.testing.assert_array_equal(step_times(np.array([0.1, 0.2, 0.1])), [1.0, 2.0, 3.0])


def check_view(result: Path, planes: np.ndarray, behind: bool = False) -> int:
    """Read `result`'s view with meshio and VTK and compare every grid with the HDF5 file (one
    family: yarn k in the plane y = `planes`[k]); the number of time steps: the finished
    steps, or (`behind`, after a kill -9) at most those."""
    view = result.with_suffix(".xdmf")
    with h5py.File(result, "r") as h5:
        count = int(h5["steps_done"][0])
        if behind:
            listed = len(read_meshio(view)["steps"])
            assert 1 <= listed <= count
            count = listed
        steps = {name: h5[f"steps/{name}"][:count] for name in
                 ("positions", "contact_force", "anchors", "load")}
        reference = h5["reference/positions"][()]
        crossings = h5["reference/crossing_nodes"][()]
        has_point_data = "xdmf" in h5["steps"]
    yarns, nodes = reference.shape[:2]
    force = np.zeros((count, yarns, nodes))
    slip = np.zeros((count, yarns, nodes))
    force[:, :, crossings] = steps["contact_force"]
    slip[:, :, crossings] = steps["positions"][:, :, crossings, 0] - steps["anchors"]
    plane = np.repeat(planes, nodes)
    point_data = {"plane": [plane] * count}
    if has_point_data:
        point_data.update(contact_force=force.reshape(count, -1), slip=slip.reshape(count, -1))
    expected = {"as_woven": to_3d(reference, planes), "as_woven_plane": plane,
                "segments": chains([(yarns, nodes)]),
                "yarn": np.repeat(np.arange(yarns), nodes - 1),
                "times": expected_times(steps["load"][:, 0]),
                "points": [to_3d(p, planes) for p in steps["positions"]],
                "point_data": point_data}
    assert check_both(view, expected) == count
    text = view.read_text()  # each step's load value, for a reader that shows it
    assert re.findall(r'<Information Name="load" Value="([^"]*)"', text) == \
        [repr(float(v)) for v in steps["load"][:, 0]]
    return count


def test_the_view_holds_every_step_of_a_run(finished):
    """Two warps of a fabric of width 12 mm with 4 warps: planes y = (k - 1/2) 3 mm."""
    planes = (np.arange(2) + 0.5) * (0.012 / 4)
    assert check_view(finished, planes) == len(LOADS)
    with h5py.File(finished, "r") as h5:  # friction made slips that are not all 0
        assert np.any(h5["steps/xdmf/slip"][()] != 0) and np.all(h5["steps/contact_force"][()] > 0)


def test_the_view_refers_to_the_hdf5_file_and_copies_no_data(finished):
    """Every DataItem of the view is a whole dataset of the result file (no inline numbers, no
    HyperSlab, which meshio cannot read); the step arrays are HDF5 virtual datasets into the
    file's rows, so the view stores no number twice; only finished steps are listed."""
    text = finished.with_suffix(".xdmf").read_text()
    items = re.findall(r"<DataItem ([^>]*)>([^<]*)</DataItem>", text)
    assert items and all('Format="HDF"' in attrs for attrs, _ in items)
    assert "HyperSlab" not in text and "X_Y_Z" not in text and "xi:include" not in text
    names = {path.split(":/")[1] for _, path in items}
    assert {path.split(":")[0] for _, path in items} == {finished.name}
    with h5py.File(finished, "r") as h5:
        for name in names:
            dataset = h5[name]
            assert dataset.is_virtual == (name not in ("view/plane", "view/segments", "view/yarn"))
            if dataset.is_virtual:
                assert {source.file_name for source in dataset.virtual_sources()} == {"."}
        nodes = h5["reference/positions"].shape[0] * h5["reference/positions"].shape[1]
        assert max(h5[name].size for name in names if not h5[name].is_virtual) <= 2 * nodes
        views = []
        h5["view"].visititems(lambda name, obj: views.append(f"view/{name}")
                              if isinstance(obj, h5py.Dataset) else None)
        for name in views:  # every dataset has its units (dynfab.results.file.UNITS)
            assert h5[name].attrs["units"] == units_of(name), name
    assert text.count("<Grid Name=\"steps ") == len(LOADS)
    assert {int(n.split("/")[3]) for n in names if n.startswith("view/steps/")} == \
        set(range(1, len(LOADS) + 1))


def interrupt_after(count: int):
    """A progress callback that interrupts the run (as Ctrl-C does) after `count` steps."""
    seen = []

    def progress(line):
        seen.append(line)
        if len(seen) == count:
            raise KeyboardInterrupt

    return progress


def test_an_interrupted_run_lists_only_its_finished_steps_and_resume_completes_it(
        finished, tmp_path):
    out = tmp_path / "cut.h5"
    with pytest.raises(KeyboardInterrupt):
        run_to_file(scene(LOADS), "static", out, progress=interrupt_after(2))
    with h5py.File(out, "r") as h5:  # untrimmed, as a kill leaves it: rows 3 and 4 unwritten
        assert h5["steps/positions"].shape[0] == len(LOADS) and h5["steps_done"][0] == 2
    planes = (np.arange(2) + 0.5) * (0.012 / 4)
    assert check_view(out, planes) == 2
    out.with_suffix(".xdmf").unlink()  # a kill -9 before the view was written: rewrite it
    assert dynfab.write_xdmf(out) == out.with_suffix(".xdmf")
    assert check_view(out, planes) == 2
    run_to_file(scene(LOADS), "static", out, resume=True)
    assert check_view(out, planes) == len(LOADS)
    with h5py.File(out, "r") as h5, h5py.File(finished, "r") as full:
        for name in ("positions", "xdmf/contact_force", "xdmf/slip"):
            np.testing.assert_array_equal(h5[f"steps/{name}"][()], full[f"steps/{name}"][()])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.h5", "cut.xdmf"]


def test_after_kill_minus_9_the_view_lists_finished_steps_only(tmp_path):
    """A run killed mid-way (SIGKILL: no handler runs) leaves a view of finished steps, perhaps
    fewer than the file holds (`XdmfSync` skips rewrites of short steps), never more;
    --resume completes it."""
    fig5 = Path(__file__).resolve().parents[1] / "runs" / "paper_fig5.toml"
    out = tmp_path / "killed.h5"
    run = [sys.executable, "-m", "dynfab.cli", "run", str(fig5), "--out", str(out), "--quiet"]
    child = subprocess.Popen(run, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while (finished_counts(out) or (0, 0))[0] < 5 and time.monotonic() < deadline:
        time.sleep(0.002)
    child.send_signal(signal.SIGKILL)
    child.wait()
    assert 5 <= finished_counts(out)[0] < 40, "the kill must land mid-run"
    planes = (np.arange(2) + 0.5) * (0.1 / 10)  # a sweep: L / 10
    check_view(out, planes, behind=True)
    done = subprocess.run(run + ["--resume"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert check_view(out, planes) == 40


def test_a_sweep_is_spaced_by_a_tenth_of_the_length(tmp_path):
    """The yarns of a sweep are not neighbours in a fabric: planes (k - 1/2) L / 10."""
    swept = make_scene(
        sweep={"friction.alpha": [0.2, 0.0]},
        geometry={"length": 0.025, "segments": 32, "crossings": 4, "amplitude": 0.5e-3,
                  "reference": "prestressed"},
        warp=PAPER_WARP, weft=PAPER_WEFT, friction=PAPER_FRICTION,
        load={"control": "force", "values": [0.05, 0.1]})
    out = tmp_path / "sweep.h5"
    run_to_file(swept, "static", out)
    assert check_view(out, (np.arange(2) + 0.5) * (0.025 / 10)) == 2


def test_the_xdmf_command_rewrites_the_view_and_refuses_a_missing_file(finished, tmp_path):
    copy = tmp_path / "copy.h5"
    copy.write_bytes(finished.read_bytes())
    done = subprocess.run([sys.executable, "-m", "dynfab.cli", "xdmf", str(copy)],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"wrote {copy.with_suffix('.xdmf')}"
    assert copy.with_suffix(".xdmf").read_text() == finished.with_suffix(".xdmf").read_text() \
        .replace(finished.name, copy.name)
    with h5py.File(copy, "r+") as h5:  # the copy's views read the copy, not the original
        h5["steps/positions"][0, :, :, 1] += 1e-3  # z: the slip stays that of x
    assert check_view(copy, (np.arange(2) + 0.5) * (0.012 / 4)) == len(LOADS)
    missing = subprocess.run([sys.executable, "-m", "dynfab.cli", "xdmf", str(tmp_path / "no.h5")],
                             capture_output=True, text=True)
    assert missing.returncode == 2 and "Traceback" not in missing.stderr
    assert missing.stderr.strip().splitlines() == [
        f"dynfab: error: result file '{tmp_path / 'no.h5'}' does not exist"]


def test_a_file_written_before_the_views_and_point_data_resumes_and_gets_its_views(
        finished, tmp_path):
    """An older file (no view/, no steps/xdmf/*, stress or slip_ratio: `ResultFile` without
    `views`) keeps its keys on --resume and gets view/ (one rewrite): its view shows the
    geometry, ``position`` and ``plane``, no contact_force or slip."""
    full = dynfab.read_results(finished)
    first = {name: rows[0] for name, rows in full.steps.items()
             if not name.startswith("xdmf/") and name not in ("stress", "slip_ratio")}
    old = tmp_path / "old.h5"
    with ResultFile.create(old, attrs=full.attrs, reference=full.reference,
                           step_capacity=len(LOADS)) as f:
        f.append_step(first)
    with h5py.File(old, "r") as h5:
        assert "view" not in h5
    run_to_file(scene(LOADS), "static", old, resume=True)
    with h5py.File(old, "r") as h5:
        assert "xdmf" not in h5["steps"] and h5["steps_done"][0] == len(LOADS)
        assert "stress" not in h5["steps"] and "slip_ratio" not in h5["steps"]
    assert check_view(old, (np.arange(2) + 0.5) * (0.012 / 4)) == len(LOADS)


def write_frames(out: Path, times, capacity: int) -> list[dict]:
    """A transient file (`frames/*`) written with `ResultFile` alone (no views), as a file of
    an older dynfab: one yarn of 9 nodes, frame data made up, nodal data by the test's own
    rule; the frames written."""
    rng = np.random.default_rng(7)
    yarns, nodes, crossings = 1, 9, np.array([2, 6])
    attrs = {"scene": "", "solver": "dynamic", "projected_length": 0.02}
    reference = {"positions": rng.normal(size=(yarns, nodes, 2)), "crossing_nodes": crossings}
    frames = []
    with ResultFile.create(out, attrs=attrs, reference=reference, frame_capacity=capacity) as f:
        for time in times:
            frame = {"time": time, "positions": rng.normal(size=(yarns, nodes, 2)),
                     "contact_force": rng.random((yarns, 2)), "anchors": rng.normal(size=(yarns, 2))}
            force, slip = np.zeros((yarns, nodes)), np.zeros((yarns, nodes))
            force[:, crossings] = frame["contact_force"]
            slip[:, crossings] = frame["positions"][:, crossings, 0] - frame["anchors"]
            frame.update({"xdmf/contact_force": force, "xdmf/slip": slip})
            f.append_frame(frame)
            frames.append(frame)
    return frames


def test_a_transient_file_lists_its_frames_at_their_times(tmp_path):
    """Frames (a transient run, `frames/*`): one grid per finished frame, Time = its time [s].
    The file has no views yet: `write_xdmf` adds them (one atomic rewrite), its frames and
    counts unchanged."""
    out = tmp_path / "transient.h5"
    frames = write_frames(out, (0.0, 1e-4, 3e-4), capacity=5)
    before = dynfab.read_results(out)
    view = dynfab.write_xdmf(out)
    after = dynfab.read_results(out)
    assert after.frame_count == 3 and set(after.frames) == set(before.frames)
    for name, values in before.frames.items():
        np.testing.assert_array_equal(after.frames[name], values, err_msg=name)
    plane = np.array([0.5 * (0.02 / 10)])  # one yarn, no width: L / 10
    reference = before.reference["positions"]
    expected = {"as_woven": to_3d(reference, plane), "as_woven_plane": np.repeat(plane, 9),
                "segments": chains([(1, 9)]), "yarn": np.zeros(8),
                "times": [f["time"] for f in frames],
                "points": [to_3d(f["positions"], plane) for f in frames],
                "point_data": {"plane": [np.repeat(plane, 9)] * 3,
                               "contact_force": [f["xdmf/contact_force"].ravel() for f in frames],
                               "slip": [f["xdmf/slip"].ravel() for f in frames]}}
    assert check_both(view, expected) == 3


def test_a_file_being_written_without_views_is_refused_in_one_line(tmp_path):
    """Adding views needs the writer lock: a file another writer holds (here a `ResultFile`
    open in this process, an older dynfab's run elsewhere) is refused, the file untouched."""
    out = tmp_path / "busy.h5"
    write_frames(out, (0.0,), capacity=1)
    data = out.read_bytes()
    writer = ResultFile.resume(out)
    try:
        with pytest.raises(dynfab.UserError, match="being written by another dynfab process"):
            dynfab.write_xdmf(out)
    finally:
        writer.close(trim=False)
    assert out.read_bytes() == data and not out.with_suffix(".xdmf").exists()


RUNS = Path(__file__).resolve().parents[1] / "runs"


def fabric_scene(name: str):
    """A fabric scene of runs/, cut for speed (static runs of a few steps): the periodic
    biaxial cell (3 steps of its path); the affine strip as a 4 x 4 patch of the same yarns
    and pitch (2 steps of 0.5 N, weft ends free); the pull-out (fixed planes, its crossings
    fixed pairs of nodes) as a 4 x 4 patch of the same segment length, warp 2 pulled 0.1 mm
    after two steps of weft stretching."""
    from dynfab.scene import parse_scene_text

    text = pullout_text() if name == "fabric_pullout" else (RUNS / f"{name}.toml").read_text()
    if name == "fabric_strip":
        for old, new in (("segments = 224", "segments = 56"), ("crossings = 16", "crossings = 4"),
                         ("count = 16", "count = 4"), ("length = 0.1", "length = 0.025"),
                         ("steps = 10", "steps = 2")):
            text = text.replace(old, new)
    elif name == "fabric_pullout":
        for old, new in (("segments = 112", "segments = 56"), ("crossings = 8", "crossings = 4"),
                         ("count = 8", "count = 4"), ("warp = 4", "warp = 2"),
                         ("length = 0.05", "length = 0.025")):
            text = text.replace(old, new)
        text = re.sub(r"^values = .*$", "values = [0, 0, 1e-4]", text, flags=re.M)
        text = re.sub(r"^weft_values = .*$", "weft_values = [5e-5, 1e-4, 1e-4]", text, flags=re.M)
    else:
        text = re.sub(r"^values = \[([^,]*),([^,]*),([^,]*),.*$", r"values = [\1,\2,\3]", text,
                      flags=re.M)
        text = re.sub(r"^weft_values = \[([^,]*),([^,]*),([^,]*),.*$", r"weft_values = [\1,\2,\3]",
                      text, flags=re.M)
    return parse_scene_text(text)


@pytest.mark.parametrize("name", ["fabric_biaxial", "fabric_strip", "fabric_pullout"])
def test_a_fabric_view_draws_both_families_where_their_planes_are(tmp_path, name):
    """docs/model.md section 10: warp k lies in y = Y_k, weft j in x = X_j. With "affine" planes
    and on the periodic cell the planes move, X_j = (j - 1/2)(L + u_wa)/n_we with u_wa the
    warps' mean end displacement (on the cell the stretched cell length), Y_k likewise; with
    fixed planes (the clamped pull-out) they stay at their as-woven (j - 1/2) L / n_we,
    (k - 1/2) L_we / n_wa. The view, read with meshio and with VTK, holds the warps' nodes then
    the wefts' at those planes at every step, point data ``plane`` = Y_k or X_j, and the slip
    s = x - X_j - xi_x (10.7) (y - Y_k - xi_y for a weft) and contact force R at the crossing
    nodes of both families. Moving planes must have moved by far more than rounding."""
    scene = fabric_scene(name)
    out = tmp_path / f"{name}.h5"
    run_to_file(scene, "static", out)
    n_wa, n_we = scene.weft.count, scene.geometry.crossings
    L = scene.geometry.length
    L_we = scene.weft.length or L
    with h5py.File(out, "r") as h5:
        count = int(h5["steps_done"][0])
        steps = {key: h5[f"steps/{key}"][:count] for key in
                 ("positions", "weft_positions", "end_displacement", "anchors", "warp_planes",
                  "weft_planes", "contact_force", "load")}
        crossings = h5["reference/crossing_nodes"][()]
        weft_crossings = h5["reference/weft_crossing_nodes"][()]
        reference = h5["reference/positions"][()], h5["reference/weft_positions"][()]
        assert h5["steps/warp_planes"].attrs["units"] == "m"
    assert count == len(scene.load.values)
    X0 = (np.arange(n_we) + 0.5) * (L / n_we)  # the as-woven planes
    Y0 = (np.arange(n_wa) + 0.5) * (L_we / n_wa)
    if name == "fabric_pullout":  # fixed planes
        X, Y = np.tile(X0, (count, 1)), np.tile(Y0, (count, 1))
        np.testing.assert_allclose(steps["weft_planes"], X, rtol=0, atol=4 * EPS_M * L)
        assert np.abs(steps["positions"][-1] - reference[0]).max() > 1e6 * EPS_M * L  # pulled
    else:
        u = steps["end_displacement"]
        X = (np.arange(n_we) + 0.5) * (L + u[:, :n_wa].mean(axis=1, keepdims=True)) / n_we
        Y = (np.arange(n_wa) + 0.5) * (L_we + u[:, n_wa:].mean(axis=1, keepdims=True)) / n_wa
        np.testing.assert_allclose(steps["weft_planes"], X, rtol=0, atol=4 * EPS_M * L)
        np.testing.assert_allclose(steps["warp_planes"], Y, rtol=0, atol=4 * EPS_M * L_we)
        assert np.abs(X[-1] - X0).min() > 1e6 * EPS_M * L  # moved
        X, Y = steps["weft_planes"], steps["warp_planes"]  # the file's, to the last bit
    (_, N1, _), (_, M1, _) = reference[0].shape, reference[1].shape

    def nodes(warps, wefts, y, x):
        """(P, 3): warp k at (x, y_k, z), then weft j at (x_j, y, z)."""
        return np.concatenate([
            np.column_stack([warps[..., 0].ravel(), np.repeat(y, N1), warps[..., 1].ravel()]),
            np.column_stack([np.repeat(x, M1), wefts[..., 0].ravel(), wefts[..., 1].ravel()])])

    force, slip = np.zeros((count, n_wa * N1 + n_we * M1)), np.zeros((count, n_wa * N1 + n_we * M1))
    for k in range(count):
        warps, wefts = steps["positions"][k], steps["weft_positions"][k]
        f_wa, f_we, s_wa, s_we = (np.zeros((n_wa, N1)), np.zeros((n_we, M1)),
                                  np.zeros((n_wa, N1)), np.zeros((n_we, M1)))
        f_wa[:, crossings] = steps["contact_force"][k]
        f_we[:, weft_crossings] = steps["contact_force"][k].T
        s_wa[:, crossings] = warps[:, crossings, 0] - X[k] - steps["anchors"][k][..., 0]
        s_we[:, weft_crossings] = (wefts[:, weft_crossings, 0] - Y[k]
                                   - steps["anchors"][k][..., 1].T)
        force[k] = np.concatenate([f_wa.ravel(), f_we.ravel()])
        slip[k] = np.concatenate([s_wa.ravel(), s_we.ravel()])
    expected = {
        "as_woven": nodes(*reference, Y0, X0),
        "as_woven_plane": np.concatenate([np.repeat(Y0, N1), np.repeat(X0, M1)]),
        "segments": chains([(n_wa, N1), (n_we, M1)]),
        "yarn": np.concatenate([np.repeat(np.arange(n_wa), N1 - 1),
                                np.repeat(n_wa + np.arange(n_we), M1 - 1)]),
        "times": expected_times(steps["load"][:, 0]),
        "points": [nodes(steps["positions"][k], steps["weft_positions"][k], Y[k], X[k])
                   for k in range(count)],
        "point_data": {"plane": [np.concatenate([np.repeat(Y[k], N1), np.repeat(X[k], M1)])
                                 for k in range(count)],
                       "contact_force": force, "slip": slip},
        "atol": {"slip": 4 * EPS_M * max(L, L_we)},  # (10.7): the file's three-term sum
    }
    assert check_both(out.with_suffix(".xdmf"), expected) == count
    assert np.any(slip != 0) and np.any(force != 0)


EPS_M = np.finfo(float).eps
"""Machine epsilon: the planes are sums and products of a few rounded lengths."""
