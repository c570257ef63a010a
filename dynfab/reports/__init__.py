"""Reports: studies that run many scenes and write data (CSV/JSON/HDF5) and figures (PNG).

One module a report, each with a `--quick` mode the tests run: `convergence`
(mesh, load increment, stick stiffness), and later `precision`, `stability`
and `figures`.
"""
