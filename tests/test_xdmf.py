"""The ParaView view of a result file (`dynfab.xdmf`), read back independently with meshio.

meshio's XDMF time-series reader (5.3.5) parses the XML, the temporal
collection, the times, the Polyline topology and the node-centred attributes,
but reads an HDF5 DataItem only whole and knows neither ``HyperSlab`` DataItems
nor ``X_Y_Z`` geometry nor ``xi:include``, which the view uses so that it
copies no data. `SlabReader` adds exactly those three, following the XDMF 3
model (a HyperSlab's first child holds start, stride and count per dimension;
X_Y_Z holds the x, y and z arrays; an include is an XPath into the same file);
everything else is meshio's. Expected values come from the HDF5 file read with
h5py and from the scene (plane spacing), never from dynfab.xdmf.
"""

import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from xml.etree import ElementTree

import h5py
import meshio.xdmf as meshio_xdmf
import numpy as np
import pytest
from independent import PAPER_FRICTION, PAPER_WARP, PAPER_WEFT, make_scene

import dynfab
from dynfab.results import ResultFile, finished_counts
from dynfab.run import run_to_file

XINCLUDE = "{http://www.w3.org/2001/XInclude}include"


class SlabReader(meshio_xdmf.TimeSeriesReader):
    """meshio's reader plus HyperSlab DataItems, X_Y_Z geometry and xi:include (see above)."""

    def __init__(self, filename):
        super().__init__(filename)
        self.root = ElementTree.parse(filename).getroot()

    def resolve(self, element):
        """The element an ``xi:include`` points to (itself otherwise)."""
        if element.tag != XINCLUDE:
            return element
        xpath = re.fullmatch(r"xpointer\((.*)\)", element.get("xpointer")).group(1)
        found = self.root.findall("." + xpath)
        assert len(found) == 1, xpath
        return found[0]

    def _read_data_item(self, data_item):
        data_item = self.resolve(data_item)
        if data_item.get("ItemType") != "HyperSlab":
            return super()._read_data_item(data_item)
        selection, source = list(data_item)
        start, stride, count = np.array(selection.text.split(), dtype=int).reshape(3, -1)
        whole = super()._read_data_item(source)
        assert whole.shape == tuple(int(d) for d in source.get("Dimensions").split())
        return whole[tuple(slice(b, b + s * c, s) for b, s, c in zip(start, stride, count))]

    def points(self, grid) -> np.ndarray:
        """The (points, 3) coordinates of a grid (X_Y_Z: three arrays, one per axis)."""
        geometry = grid.find("Geometry")
        assert geometry.get("GeometryType") == "X_Y_Z"
        return np.column_stack([self._read_data_item(item).ravel() for item in geometry])

    def read_points_cells(self):
        """meshio's topology; the points of the mesh grid through `points`."""
        geometry = self.mesh_grid.find("Geometry")
        self.mesh_grid.remove(geometry)  # meshio refuses X_Y_Z: read it here instead
        try:
            _, cells = super().read_points_cells()
        finally:
            self.mesh_grid.append(geometry)
        return self.points(self.mesh_grid), cells


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


def check_view(result: Path, planes: np.ndarray, behind: bool = False) -> int:
    """Read `result`'s XDMF with `SlabReader` and compare every grid with the HDF5 file; the
    number of time steps: the finished steps, or (`behind`, after a kill -9) at most those."""
    with h5py.File(result, "r") as h5:
        count = int(h5["steps_done"][0])
        if behind:
            listed = SlabReader(result.with_suffix(".xdmf")).num_steps
            assert 1 <= listed <= count
            count = listed
        steps = {name: h5[f"steps/{name}"][:count] for name in
                 ("positions", "contact_force", "anchors")}
        reference = h5["reference/positions"][()]
        crossings = h5["reference/crossing_nodes"][()]
    yarns, nodes = reference.shape[:2]
    with SlabReader(result.with_suffix(".xdmf")) as reader:
        assert reader.num_steps == count
        points, cells = reader.read_points_cells()
        np.testing.assert_array_equal(points, to_3d(reference, planes))
        assert [block.type for block in cells] == ["line"]  # meshio's name of Polyline
        np.testing.assert_array_equal(cells[0].data,
                                      np.arange(yarns * nodes).reshape(yarns, nodes))
        others = np.setdiff1d(np.arange(nodes), crossings)
        for k in range(count):
            time, point_data, _ = reader.read_data(k)
            assert time == k + 1  # the step number
            np.testing.assert_array_equal(reader.points(reader.collection[k]),
                                          to_3d(steps["positions"][k], planes))
            force = point_data["contact_force"].reshape(yarns, nodes)
            slip = point_data["slip"].reshape(yarns, nodes)
            np.testing.assert_array_equal(force[:, crossings], steps["contact_force"][k])
            np.testing.assert_array_equal(
                slip[:, crossings], steps["positions"][k][:, crossings, 0] - steps["anchors"][k])
            assert not force[:, others].any() and not slip[:, others].any()
    return count


def test_the_view_holds_every_step_of_a_run(finished):
    """Two warps of a fabric of width 12 mm with 4 warps: planes y = (k - 1/2) 3 mm."""
    planes = (np.arange(2) + 0.5) * (0.012 / 4)
    assert check_view(finished, planes) == len(LOADS)
    with h5py.File(finished, "r") as h5:  # friction made slips that are not all 0
        assert np.any(h5["steps/xdmf/slip"][()] != 0) and np.all(h5["steps/contact_force"][()] > 0)


def test_the_view_refers_to_the_hdf5_file_and_copies_no_data(finished):
    text = finished.with_suffix(".xdmf").read_text()
    assert f"{finished.name}:/steps/positions" in text
    largest_inline = max(len(m) for m in re.findall(r'Format="XML"[^>]*>([^<]*)<', text))
    with h5py.File(finished, "r") as h5:  # inline XML: topology and planes, not the steps
        nodes = h5["reference/positions"].shape[0] * h5["reference/positions"].shape[1]
    assert largest_inline < 40 * nodes
    assert text.count("<Grid Name=\"steps ") == len(LOADS)


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
    missing = subprocess.run([sys.executable, "-m", "dynfab.cli", "xdmf", str(tmp_path / "no.h5")],
                             capture_output=True, text=True)
    assert missing.returncode == 2 and "Traceback" not in missing.stderr
    assert missing.stderr.strip().splitlines() == [
        f"dynfab: error: result file '{tmp_path / 'no.h5'}' does not exist"]


def test_a_file_written_before_the_point_data_resumes_and_gets_geometry_only(finished, tmp_path):
    """An older file (no steps/xdmf/*, stress or slip_ratio) keeps its keys on --resume; its
    view has no point data."""
    full = dynfab.read_results(finished)
    first = {name: rows[0] for name, rows in full.steps.items()
             if not name.startswith("xdmf/") and name not in ("stress", "slip_ratio")}
    old = tmp_path / "old.h5"
    with ResultFile.create(old, attrs=full.attrs, reference=full.reference,
                           step_capacity=len(LOADS)) as f:
        f.append_step(first)
    run_to_file(scene(LOADS), "static", old, resume=True)
    with h5py.File(old, "r") as h5:
        assert "xdmf" not in h5["steps"] and h5["steps_done"][0] == len(LOADS)
        assert "stress" not in h5["steps"] and "slip_ratio" not in h5["steps"]
    text = old.with_suffix(".xdmf").read_text()
    assert text.count('<Grid Name="steps ') == len(LOADS) and "<Attribute" not in text


def test_paraview_reader_of_vtk_reads_the_view(finished):
    """ParaView's "XDMF Reader" (VTK's Xdmf2 reader), where the vtk package is installed:
    the same points, polylines and point data per time step."""
    xdmf2 = pytest.importorskip("vtkmodules.vtkIOXdmf2")
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline

    reader = xdmf2.vtkXdmfReader()
    reader.SetFileName(str(finished.with_suffix(".xdmf")))
    reader.UpdateInformation()
    times = reader.GetOutputInformation(0).Get(vtkStreamingDemandDrivenPipeline.TIME_STEPS())
    assert list(times) == [1.0, 2.0, 3.0, 4.0]
    with h5py.File(finished, "r") as h5:
        positions, force = h5["steps/positions"][()], h5["steps/contact_force"][()]
        crossings = h5["reference/crossing_nodes"][()]
    planes = (np.arange(2) + 0.5) * (0.012 / 4)
    for k, time in enumerate(times):
        reader.UpdateTimeStep(time)
        yarns = reader.GetOutputDataObject(0).GetBlock(1)  # block 0: the as-woven state
        np.testing.assert_array_equal(vtk_to_numpy(yarns.GetPoints().GetData()),
                                      to_3d(positions[k], planes))
        assert yarns.GetNumberOfCells() == 2 and yarns.GetCellType(0) == 4  # VTK_POLY_LINE
        nodal = vtk_to_numpy(yarns.GetPointData().GetArray("contact_force")).reshape(2, -1)
        np.testing.assert_array_equal(nodal[:, crossings], force[k])


def test_a_transient_file_lists_its_frames_at_their_times(tmp_path):
    """Frames (a transient run, `frames/*`): one grid per finished frame, Time = its time [s];
    written here with `ResultFile` (frame data made up, nodal data by the test's own rule)."""
    rng = np.random.default_rng(7)
    yarns, nodes, crossings = 1, 9, np.array([2, 6])
    out = tmp_path / "transient.h5"
    attrs = {"scene": "", "solver": "dynamic", "projected_length": 0.02}
    reference = {"positions": rng.normal(size=(yarns, nodes, 2)), "crossing_nodes": crossings}
    frames = []
    with ResultFile.create(out, attrs=attrs, reference=reference, frame_capacity=5) as f:
        for time in (0.0, 1e-4, 3e-4):
            frame = {"time": time, "positions": rng.normal(size=(yarns, nodes, 2)),
                     "contact_force": rng.random((yarns, 2)), "anchors": rng.normal(size=(yarns, 2))}
            force, slip = np.zeros((yarns, nodes)), np.zeros((yarns, nodes))
            force[:, crossings] = frame["contact_force"]
            slip[:, crossings] = frame["positions"][:, crossings, 0] - frame["anchors"]
            frame.update({"xdmf/contact_force": force, "xdmf/slip": slip})
            f.append_frame(frame)
            frames.append(frame)
    view = dynfab.write_xdmf(out)
    with SlabReader(view) as reader:
        assert reader.num_steps == 3
        reader.read_points_cells()
        for k, frame in enumerate(frames):
            time, point_data, _ = reader.read_data(k)
            assert time == frame["time"]
            np.testing.assert_array_equal(reader.points(reader.collection[k]),
                                          to_3d(frame["positions"], np.array([0.5 * (0.02 / 10)])))
            np.testing.assert_array_equal(point_data["contact_force"].ravel(),
                                          frame["xdmf/contact_force"].ravel())
            np.testing.assert_array_equal(point_data["slip"].ravel(), frame["xdmf/slip"].ravel())


RUNS = Path(__file__).resolve().parents[1] / "runs"


def fabric_scene(name: str):
    """A fabric scene of runs/ whose planes move, cut for speed (static runs of a few steps):
    the periodic biaxial cell (3 steps of its path), the affine strip as a 4 x 4 patch of the
    same yarns and pitch (2 steps of 0.5 N, weft ends free)."""
    from dynfab.scene import parse_scene_text

    text = (RUNS / f"{name}.toml").read_text()
    if name == "fabric_strip":
        for old, new in (("segments = 224", "segments = 56"), ("crossings = 16", "crossings = 4"),
                         ("count = 16", "count = 4"), ("length = 0.1", "length = 0.025"),
                         ("max = 1.0", "max = 1.0"), ("steps = 10", "steps = 2")):
            text = text.replace(old, new)
    else:
        text = re.sub(r"^values = \[([^,]*),([^,]*),([^,]*),.*$", r"values = [\1,\2,\3]", text,
                      flags=re.M)
        text = re.sub(r"^weft_values = \[([^,]*),([^,]*),([^,]*),.*$", r"weft_values = [\1,\2,\3]",
                      text, flags=re.M)
    return parse_scene_text(text)


def grids_of(reader: SlabReader, collection: str) -> list:
    """The step grids of the temporal collection named `collection`."""
    found = [g for g in reader.root.iter("Grid") if g.get("Name") == collection]
    assert len(found) == 1
    return list(found[0])


def node_attribute(reader: SlabReader, grid, name: str) -> np.ndarray:
    attributes = [a for a in grid.iter("Attribute") if a.get("Name") == name]
    assert len(attributes) == 1
    return reader._read_data_item(list(attributes[0])[0]).ravel()


@pytest.mark.parametrize("name", ["fabric_biaxial", "fabric_strip"])
def test_a_fabric_view_draws_moving_planes_where_they_are(tmp_path, name):
    """docs/model.md section 10: with "affine" planes and on the periodic cell the planes move,
    X_j = (j - 1/2)(L + u_wa)/n_we with u_wa the warps' mean end displacement (on the cell the
    stretched cell length), Y_k likewise. Each step's grid of the view (read back with
    `SlabReader`) draws warp k in y = Y_k and weft j in x = X_j, computed here from the
    file's end displacements and the scene's lengths, and its point data `slip` at the
    crossing nodes is the slip s = x - X_j - xi (10.7) of the file's anchors; the as-woven
    grids keep the as-woven planes. The planes must have moved by far more than rounding."""
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
                  "weft_planes")}
        crossings = h5["reference/crossing_nodes"][()]
        assert h5["steps/warp_planes"].attrs["units"] == "m"
    u = steps["end_displacement"]
    X = (np.arange(n_we) + 0.5) * (L + u[:, :n_wa].mean(axis=1, keepdims=True)) / n_we
    Y = (np.arange(n_wa) + 0.5) * (L_we + u[:, n_wa:].mean(axis=1, keepdims=True)) / n_wa
    np.testing.assert_allclose(steps["weft_planes"], X, rtol=0, atol=4 * EPS_M * L)
    np.testing.assert_allclose(steps["warp_planes"], Y, rtol=0, atol=4 * EPS_M * L_we)
    assert np.abs(X[-1] - (np.arange(n_we) + 0.5) * L / n_we).min() > 1e6 * EPS_M * L  # moved
    reader = SlabReader(out.with_suffix(".xdmf"))
    warp_grids, weft_grids = grids_of(reader, "warp yarns"), grids_of(reader, "weft yarns")
    assert len(warp_grids) == len(weft_grids) == count == len(scene.load.values)
    for k in range(count):
        warps, wefts = steps["positions"][k], steps["weft_positions"][k]
        nodes_wa, nodes_we = warps.shape[1], wefts.shape[1]
        expected = np.column_stack([warps[..., 0].ravel(), np.repeat(steps["warp_planes"][k], nodes_wa),
                                    warps[..., 1].ravel()])
        np.testing.assert_array_equal(reader.points(warp_grids[k]), expected)
        expected = np.column_stack([np.repeat(steps["weft_planes"][k], nodes_we),
                                    wefts[..., 0].ravel(), wefts[..., 1].ravel()])
        np.testing.assert_array_equal(reader.points(weft_grids[k]), expected)
        slip = node_attribute(reader, warp_grids[k], "slip").reshape(n_wa, nodes_wa)
        np.testing.assert_allclose(
            slip[:, crossings],
            warps[:, crossings, 0] - steps["weft_planes"][k] - steps["anchors"][k][..., 0],
            rtol=0, atol=4 * EPS_M * L)
    as_woven = [g for g in reader.root.iter("Grid") if g.get("Name") == "as-woven weft yarns"][0]
    x = reader.points(as_woven)[:, 0]
    np.testing.assert_allclose(np.unique(x), (np.arange(n_we) + 0.5) * L / n_we, rtol=1e-15)


EPS_M = np.finfo(float).eps
"""Machine epsilon: the planes are sums and products of a few rounded lengths."""
