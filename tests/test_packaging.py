"""The packages a (non-editable) install gets are found, not listed: every folder under dynfab/
holding Python files, and kernels/ installed as dynfab.kernels (setup.py). A list in
pyproject.toml once left dynfab.model.fabric out of `pip install .`. .ci/run checks the built
wheel itself (.ci/check_wheel.py); here, the package list against the folders."""

import importlib.util
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def setup_script():
    """setup.py as a module (its setup() runs only as a script)."""
    spec = importlib.util.spec_from_file_location("dynfab_setup", ROOT / "setup.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def package_folders() -> dict[str, Path]:
    """Installed package name -> folder, for every folder under dynfab/ and kernels/ that
    holds a .py file (kernels/ is dynfab.kernels)."""
    folders = {}
    for top, name in (("dynfab", "dynfab"), ("kernels", "dynfab.kernels")):
        for source in (ROOT / top).rglob("*.py"):
            relative = source.parent.relative_to(ROOT / top)
            if "__pycache__" not in relative.parts:
                folders[".".join([name, *relative.parts])] = source.parent
    return folders


def test_every_package_folder_is_a_package_of_the_install():
    setup = setup_script()
    folders = package_folders()
    assert {"dynfab", "dynfab.model.fabric", "dynfab.kernels", "dynfab.model.terms"} <= set(folders)
    assert sorted(setup.packages()) == sorted(folders)
    for name, folder in folders.items():
        assert (folder / "__init__.py").exists(), f"{name}: no __init__.py, so not found"
    assert setup.package_dir() == {"dynfab.kernels": "kernels"}


def test_pyproject_lists_no_packages():
    # a list there would override what setup.py finds (and go stale again)
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    tool = config.get("tool", {}).get("setuptools", {})
    assert "packages" not in tool and "package-dir" not in tool
