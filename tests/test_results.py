"""Result files: round trip, units, refusal to clobber, resume, and crash safety under kill -9."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from dynfab.errors import UserError
from dynfab.results.file import UNITS, ResultFile, read_results, units_of

REPO = Path(__file__).resolve().parents[1]
YARNS, NODES, CROSSINGS = 2, 17, 4


def make_attrs(**extra) -> dict:
    """Root attributes of a small synthetic run."""
    return {
        "scene": "title = 'test'\n[geometry]\nlength = 0.01\n",
        "solver": "static",
        "load_control": "force",
        "projected_length": 0.01,
        "width_per_yarn": 5e-4,
        "reference_state": "as_woven",
        "title": "synthetic",
        "yarn_labels": ["warp.kawabata_K=0.02", "warp.kawabata_K=0.04"],
        **extra,
    }


def make_reference() -> dict:
    """Reference datasets: positions (yarns, N+1, 2) and crossing nodes."""
    x = np.linspace(0.0, 0.01, NODES)
    z = 1e-4 * np.sin(np.pi * x / 0.01 * CROSSINGS)
    positions = np.stack([np.stack([x, s * z], axis=-1) for s in (1, -1)])
    return {"positions": positions, "crossing_nodes": np.array([2, 6, 10, 14])}


def make_step(n: int) -> dict:
    """A synthetic load step whose every value is derived from its index ``n``."""
    rng = np.random.default_rng(n)
    return {
        "load": np.full(YARNS, 0.1 * (n + 1)),
        "end_force": np.full(YARNS, 0.1 * (n + 1)),
        "end_displacement": rng.random(YARNS),
        "positions": rng.random((YARNS, NODES, 2)),
        "contact_force": rng.random((YARNS, CROSSINGS)),
        "friction_limit": rng.random((YARNS, CROSSINGS)),
        "sliding": rng.random((YARNS, CROSSINGS)) > 0.5,
        "energy/stretch": rng.random(YARNS),
        "energy/bend": rng.random(YARNS),
        "iterations": np.full(YARNS, n + 3, dtype=np.int64),
        "wall_time": 0.5 * n,
    }


def create(path: Path, **kwargs) -> ResultFile:
    """A new result file with the synthetic attributes and reference."""
    return ResultFile.create(path, attrs=make_attrs(**kwargs), reference=make_reference())


def test_round_trip(tmp_path):
    path = tmp_path / "run.h5"
    out = create(path)
    for n in range(3):
        out.append_step(make_step(n))
    assert out.step_count == 3

    results = read_results(path)
    assert results.step_count == 3
    assert results.frames == {}
    for name, value in make_reference().items():
        np.testing.assert_array_equal(results.reference[name], value)
    for name in make_step(0):
        expected = np.stack([np.asarray(make_step(n)[name]) for n in range(3)])
        np.testing.assert_array_equal(results.steps[name], expected, err_msg=name)
        assert results.steps[name].dtype == expected.dtype, name
    assert results.steps["sliding"].dtype == bool
    assert results.steps["wall_time"].shape == (3,)
    attrs = results.attrs
    assert attrs["units"] == "SI" and attrs["solver"] == "static"
    assert attrs["scene"] == make_attrs()["scene"]
    assert attrs["yarn_labels"] == make_attrs()["yarn_labels"]
    assert attrs["projected_length"] == 0.01 and "dynfab_version" in attrs

    with h5py.File(path, "r") as h5:
        names = []
        h5.visititems(lambda name, obj: names.append(name) if isinstance(obj, h5py.Dataset) else None)
        assert len(names) == 2 + 2 + len(make_step(0))  # + steps_done, frames_done
        for name in names:
            assert h5[name].attrs["units"] == units_of(name, "force"), name
        assert h5["steps/load"].attrs["units"] == "N"
        assert h5["steps/energy/stretch"].attrs["units"] == "J"
        assert h5["steps/positions"].attrs["units"] == UNITS["steps/positions"] == "m"
        assert h5["reference/crossing_nodes"].attrs["units"] == "-"
    assert results.units["steps/wall_time"] == "s"


def test_loads_per_unit_width_and_slip_ratios_are_written_with_their_units(tmp_path):
    """`steps/stress` [N/m] (a fabric's load per unit width per family, docs/model.md
    section 10) and `steps/slip_ratio` [-] (a crossing node's slip over its segment) are
    named in UNITS, so a run can write them."""
    out = create(tmp_path / "s.h5")
    out.append_step({"stress": np.array([12.0, 0.0]), "slip_ratio": np.float64(0.25)})
    out.close()
    results = read_results(tmp_path / "s.h5")
    assert results.units["steps/stress"] == "N/m" and results.units["steps/slip_ratio"] == "-"
    np.testing.assert_array_equal(results.steps["stress"], [[12.0, 0.0]])


def test_load_units_follow_load_control(tmp_path):
    out = create(tmp_path / "d.h5", load_control="displacement")
    out.append_step({"load": np.ones(YARNS)})
    assert read_results(tmp_path / "d.h5").units["steps/load"] == "m"
    with pytest.raises(ValueError, match="load_control"):
        out.set_attrs(load_control="force")


def test_frames_and_last(tmp_path):
    path = tmp_path / "t.h5"
    out = create(path)
    for n in range(4):
        out.append_frame(
            {"time": 1e-3 * n, "positions": np.full((YARNS, NODES, 2), n), "energy/kinetic": np.full(YARNS, n)}
        )
    out.append_step(make_step(0))
    assert out.frame_count == 4 and out.step_count == 1
    assert out.last_frame()["time"] == pytest.approx(3e-3)
    np.testing.assert_array_equal(out.last_step()["positions"], make_step(0)["positions"])
    results = read_results(path)
    assert results.frame_count == 4
    np.testing.assert_allclose(results.frames["time"], 1e-3 * np.arange(4))
    assert results.units["frames/energy/kinetic"] == "J"
    assert results.units["frames/time"] == "s"


def test_create_writes_file_at_once_and_set_attrs_on_flush(tmp_path):
    path = tmp_path / "run.h5"
    out = create(path)
    assert read_results(path).step_count == 0
    out.set_attrs(title="renamed", converged=True)
    assert read_results(path).attrs["title"] == "synthetic"
    out.flush()
    attrs = read_results(path).attrs
    assert attrs["title"] == "renamed" and attrs["converged"] is True
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.h5"]


@pytest.mark.parametrize("content", [b"precious data\n", None])
def test_refuses_existing_file_and_leaves_it_untouched(tmp_path, content):
    path = tmp_path / "x.h5"
    if content is None:
        create(path).append_step(make_step(0))
    else:
        path.write_bytes(content)
    before = path.read_bytes()
    mtime = path.stat().st_mtime_ns
    with pytest.raises(UserError) as error:
        create(path)
    message = str(error.value)
    assert message == (
        f"output file '{path}' exists: pass --overwrite to replace it or --resume to continue it"
    )
    assert "\n" not in message and error.value.exit_status == 2
    assert path.read_bytes() == before and path.stat().st_mtime_ns == mtime
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.h5"]

    ResultFile.create(path, attrs=make_attrs(), reference=make_reference(), overwrite=True)
    assert read_results(path).step_count == 0


@pytest.mark.parametrize("hard_links", [True, False])
@pytest.mark.parametrize("writer_running", [False, True])
def test_create_is_exclusive_even_against_a_file_appearing_after_the_checks(
        tmp_path, monkeypatch, writer_running, hard_links):
    """Two runs on one new file: the one that publishes second must fail, not replace
    (also on a file system without hard links, where O_EXCL claims the name)."""
    import dynfab.results.file as results

    path = tmp_path / "x.h5"
    holder = []
    if not hard_links:
        def no_link(source, target):
            raise PermissionError(1, "Operation not permitted")
        monkeypatch.setattr(os, "link", no_link)

    def other_process_creates_it(target):
        if holder or path.exists():
            return
        holder.append(None)
        holder[0] = create(path)  # slips in between the existence check and publishing
        holder[0].append_step(make_step(0))
        if not writer_running:
            holder[0].close()

    monkeypatch.setattr(results, "_remove_stale_tmp", other_process_creates_it)
    with pytest.raises(UserError) as error:
        create(path)
    monkeypatch.undo()
    expected = "being written by another dynfab process" if writer_running else "exists"
    assert expected in str(error.value)
    assert read_results(path).step_count == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.h5"]


def test_resume_continues_appending(tmp_path):
    path = tmp_path / "run.h5"
    out = create(path)
    out.append_step(make_step(0))
    out.append_step(make_step(1))
    del out

    again = ResultFile.resume(path)
    assert again.step_count == 2
    np.testing.assert_array_equal(again.last_step()["positions"], make_step(1)["positions"])
    assert again.last_step()["wall_time"] == 0.5
    again.append_step(make_step(2))
    results = read_results(path)
    assert results.step_count == 3
    np.testing.assert_array_equal(results.steps["iterations"][:, 0], [3, 4, 5])
    assert results.attrs["yarn_labels"] == make_attrs()["yarn_labels"]
    with pytest.raises(ValueError, match="keys differ"):
        again.append_step({"load": np.ones(YARNS)})


def test_resume_and_read_refuse_missing_or_foreign_files(tmp_path):
    for call in (ResultFile.resume, read_results):
        with pytest.raises(UserError, match="does not exist"):
            call(tmp_path / "missing.h5")
    junk = tmp_path / "junk.h5"
    junk.write_text("not hdf5")
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as h5:
        h5["data"] = np.arange(3)
    for path in (junk, foreign):
        for call in (ResultFile.resume, read_results):
            with pytest.raises(UserError) as error:
                call(path)
            assert "\n" not in str(error.value) and str(path) in str(error.value)


def test_unknown_names_and_inconsistent_steps_are_rejected(tmp_path):
    path = tmp_path / "run.h5"
    out = create(path)
    with pytest.raises(ValueError, match="not in dynfab.results.file.UNITS"):
        out.append_step({**make_step(0), "tension": np.ones(YARNS)})
    with pytest.raises(ValueError, match="energy term"):
        out.append_step({"energy/bad-name": np.ones(YARNS)})
    with pytest.raises(ValueError, match="not in dynfab.results.file.UNITS"):
        out.append_frame({"tension": np.ones(YARNS)})
    with pytest.raises(ValueError, match="not in dynfab.results.file.UNITS"):
        ResultFile.create(tmp_path / "r.h5", attrs=make_attrs(), reference={"velocities": np.ones(3)})
    assert out.step_count == 0 and read_results(path).step_count == 0

    out.append_step(make_step(0))
    with pytest.raises(ValueError, match="keys differ"):
        out.append_step({k: v for k, v in make_step(1).items() if k != "sliding"})
    bad_shape = {**make_step(1), "positions": np.zeros((YARNS, NODES + 1, 2))}
    with pytest.raises(ValueError, match="shape"):
        out.append_step(bad_shape)
    assert out.step_count == 1 and read_results(path).step_count == 1
    with pytest.raises(ValueError, match="scene"):
        ResultFile.create(tmp_path / "s.h5", attrs={"solver": "static"}, reference={})


def test_resume_removes_temporary_files_of_dead_writers(tmp_path):
    path = tmp_path / "run.h5"
    create(path).append_step(make_step(0))
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / f"run.h5.tmp-{dead.pid}"
    stale.write_bytes(b"half a file")
    ResultFile.resume(path)
    assert not stale.exists()


CHILD = """
import sys
import numpy as np
from dynfab.results.file import ResultFile

out = ResultFile.resume(sys.argv[1])
print("ready", flush=True)
while True:
    n = out.step_count
    out.append_step({
        "load": np.full(3, float(n)),
        "end_force": np.full(3, float(n)),
        "positions": np.full((3, 101, 2), float(n)),
        "contact_force": np.full((3, 12), float(n)),
        "sliding": np.full((3, 12), n % 2 == 1),
        "energy/stretch": np.full(3, float(n)),
        "iterations": np.full(3, n),
        "wall_time": float(n),
    })
"""


def check_complete_steps(path: Path) -> int:
    """Open ``path`` with plain h5py and check it holds whole, consistent steps; return their count.

    Reads the file as the layout contract tells a script to: rows [0, steps_done)
    of every steps/ dataset are the finished steps.
    """
    with h5py.File(path, "r") as h5:
        assert h5.attrs["units"] == "SI"
        count = int(h5["steps_done"][0])
        if "steps" not in h5 or len(h5["steps"]) == 0:
            assert count == 0
            return 0
        arrays = {}
        h5["steps"].visititems(
            lambda name, obj: arrays.__setitem__(name, obj[:count]) if isinstance(obj, h5py.Dataset) else None
        )
    assert set(arrays) == {
        "load", "end_force", "positions", "contact_force", "sliding",
        "energy/stretch", "iterations", "wall_time",
    }
    for name, array in arrays.items():
        assert len(array) == count, f"steps/{name} has {len(array)} rows, steps_done is {count}"
        for n in range(count):
            expected = (n % 2 == 1) if name == "sliding" else n
            assert np.all(array[n] == expected), f"steps/{name}[{n}] is incomplete"
    return count


def test_kill_9_at_random_moments_leaves_complete_steps(tmp_path):
    path = tmp_path / "crash.h5"
    ResultFile.create(path, attrs=make_attrs(yarn_labels=["a", "b", "c"]), reference={})
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    rng = np.random.default_rng(20240607)
    counts = [0]
    for _ in range(15):
        child = subprocess.Popen(
            [sys.executable, "-c", CHILD, str(path)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=env,
        )
        try:
            ready = child.stdout.readline()
            assert ready == b"ready\n", child.stderr.read().decode()
            time.sleep(rng.uniform(0.0, 0.3))
            assert child.poll() is None, child.stderr.read().decode()
            os.kill(child.pid, signal.SIGKILL)
        finally:
            if child.poll() is None:
                child.kill()
            child.wait()
            child.stdout.close()
            child.stderr.close()
        assert child.returncode == -signal.SIGKILL
        counts.append(check_complete_steps(path))
        assert counts[-1] >= counts[-2]
    assert counts[-1] > 15, counts
    resumed = ResultFile.resume(path)
    assert resumed.step_count == counts[-1]
    assert [p.name for p in tmp_path.iterdir()] == ["crash.h5"]


def data_regions(path: Path) -> list[tuple[int, int]]:
    """Byte ranges of the raw data of every steps/ dataset and of steps_done."""
    regions = []
    with h5py.File(path, "r") as h5:
        datasets = [h5["steps_done"]]
        h5["steps"].visititems(lambda name, obj: datasets.append(obj)
                               if isinstance(obj, h5py.Dataset) else None)
        for dataset in datasets:
            if dataset.id.get_storage_size():
                start = dataset.id.get_offset()
                regions.append((start, start + dataset.id.get_storage_size()))
    return regions


def test_appends_write_raw_data_only_and_close_trims(tmp_path):
    """After the first step lays the file out, an append changes no byte outside the raw
    data of the step datasets and the count: no HDF5 metadata, so nothing a kill could
    leave half-updated. Closing trims the datasets to the finished steps."""
    path = tmp_path / "run.h5"
    out = ResultFile.create(path, attrs=make_attrs(), reference=make_reference(), step_capacity=6)
    out.append_step(make_step(0))
    before = np.frombuffer(path.read_bytes(), np.uint8).copy()
    for n in range(1, 5):
        out.append_step(make_step(n))
    after = np.frombuffer(path.read_bytes(), np.uint8).copy()
    assert after.size == before.size
    outside = np.ones(before.size, bool)
    for start, stop in data_regions(path):
        outside[start:stop] = False
    assert outside.sum() > 1000  # the metadata is there to compare
    np.testing.assert_array_equal(after[outside], before[outside])
    with h5py.File(path, "r") as h5:  # unfinished rows hold the fill value
        assert h5["steps_done"][0] == 5 and h5["steps/load"].shape[0] == 6
        assert np.isnan(h5["steps/load"][5]).all() and (h5["steps/iterations"][5] == -1).all()
    out.close()
    with h5py.File(path, "r") as h5:
        assert h5["steps_done"][0] == 5 and h5["steps/load"].shape[0] == 5
    results = read_results(path)
    for name in make_step(0):
        expected = np.stack([np.asarray(make_step(n)[name]) for n in range(5)])
        np.testing.assert_array_equal(results.steps[name], expected, err_msg=name)


def test_appends_beyond_the_capacity_grow_the_file(tmp_path):
    path = tmp_path / "run.h5"
    out = ResultFile.create(path, attrs=make_attrs(), reference=make_reference(), step_capacity=2)
    for n in range(7):
        out.append_step(make_step(n))
    assert read_results(path).step_count == 7
    np.testing.assert_array_equal(read_results(path).steps["iterations"][:, 0], np.arange(7) + 3)


def test_resume_appends_to_a_file_written_before_the_counts_existed(tmp_path):
    """Older result files have no steps_done: every row is finished, and they resume."""
    path = tmp_path / "old.h5"
    with h5py.File(path, "w") as h5:
        for key, value in make_attrs(dynfab_version="0.0", units="SI").items():
            h5.attrs[key] = value
        for name, value in make_reference().items():
            h5[f"reference/{name}"] = value
            h5[f"reference/{name}"].attrs["units"] = units_of(f"reference/{name}")
        for name in make_step(0):
            h5[f"steps/{name}"] = np.stack([np.asarray(make_step(n)[name]) for n in range(2)])
            h5[f"steps/{name}"].attrs["units"] = units_of(f"steps/{name}", "force")
    with ResultFile.resume(path) as out:
        assert out.step_count == 2
        out.append_step(make_step(2))
    results = read_results(path)
    np.testing.assert_array_equal(results.steps["iterations"][:, 0], [3, 4, 5])
