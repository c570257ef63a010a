"""The packages of dynfab, found rather than listed (the rest of the build is pyproject.toml).

Every package folder under dynfab/ is found (setuptools' find), and kernels/ installs as
`dynfab.kernels` (its subfolders too): a folder outside dynfab/ cannot be found under that
name by pyproject.toml's declarative `find`, whose names follow the folders. A package added
under either folder needs no edit here; tests/test_packaging.py checks the list against the
folders, and .ci/run checks the built wheel.
"""

from setuptools import find_packages, setup

KERNELS = "kernels"
"""The folder of the Warp kernels, installed as the package `dynfab.kernels`."""


def packages() -> list[str]:
    """dynfab and every package below it, then dynfab.kernels and every package below it."""
    found = find_packages(include=["dynfab", "dynfab.*"])
    return found + ["dynfab.kernels"] + [f"dynfab.kernels.{name}"
                                          for name in find_packages(where=KERNELS)]


def package_dir() -> dict[str, str]:
    """Where each package whose folder is not its name lives."""
    return {"dynfab.kernels": KERNELS}


if __name__ == "__main__":
    setup(packages=packages(), package_dir=package_dir())
