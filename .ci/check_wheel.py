"""Check a built dynfab wheel: every Python file of dynfab/ and kernels/ is in it, at its
installed path (kernels/ as dynfab/kernels/). Usage: python3 .ci/check_wheel.py WHEEL"""

import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def installed_paths() -> set[str]:
    """The wheel path of every .py file of the source folders."""
    paths = set()
    for top, target in (("dynfab", "dynfab"), ("kernels", "dynfab/kernels")):
        for source in (ROOT / top).rglob("*.py"):
            relative = source.relative_to(ROOT / top)
            if "__pycache__" not in relative.parts:
                paths.add(f"{target}/{relative.as_posix()}")
    return paths


def main(wheel: str) -> int:
    names = set(zipfile.ZipFile(wheel).namelist())
    missing = sorted(installed_paths() - names)
    packages = sorted({path.rsplit("/", 1)[0] for path in installed_paths()})
    if missing:
        print(f"{wheel}: {len(missing)} source files missing: {', '.join(missing)}")
        return 1
    print(f"{Path(wheel).name}: all {len(installed_paths())} source files of "
          f"{len(packages)} packages ({', '.join(packages)})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
