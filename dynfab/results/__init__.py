"""Results: the crash-safe HDF5 file (`file`), the views of a file and its XDMF (`views`,
`xdmf`), what a run prints (`summary`), and each crossing's friction state read back from a
file (`friction_states`). What a step records is the model's (`dynfab.model.observables`,
`dynfab.model.shear_force`).

`from dynfab.results import read_results, Results` keeps working: the file's public names
are looked up in `file` on first use."""

import importlib

_PUBLIC = ("Results", "read_results", "finished_counts", "MACHINE_TIMES")


def __getattr__(name: str):
    """A public name of the result file (`file`), imported on first use."""
    if name in _PUBLIC:
        return getattr(importlib.import_module("dynfab.results.file"), name)
    raise AttributeError(f"module 'dynfab.results' has no attribute {name!r}")
