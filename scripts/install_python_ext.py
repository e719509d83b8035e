"""Install the dvnav Python package into the running interpreter's site-packages from an
extension module that cargo already built, without maturin.

    target/pyenv-python/bin/python scripts/install_python_ext.py target/debug/lib_core.so python/dvnav

`make test-python` uses it so that the package's tests run the extension `make test` built with
the workspace's one feature set: `maturin develop` runs `cargo rustc` on the one crate, whose
feature resolution differs from the workspace's and rebuilt candle and everything above it.
Users build the package with `make python` (maturin, optimized); this is for tests.

What it does: replaces site-packages/dvnav with a copy of the package's Python files and the
extension named as this interpreter imports it (`_core` + EXT_SUFFIX), and removes an editable
install of the package that maturin may have left in the same environment (its `.pth` would put
the source tree, without this extension, on the path too).
"""

import shutil
import sys
import sysconfig
from pathlib import Path


def main() -> int:
    if len(sys.argv) != 3:
        print("usage: python install_python_ext.py EXTENSION.so PACKAGE_DIR", file=sys.stderr)
        return 2
    ext, package = Path(sys.argv[1]), Path(sys.argv[2])
    if not ext.is_file():
        sys.exit(f"install_python_ext: no extension at {ext}: build it first (make test, or cargo build --workspace --all-targets)")
    if not (package / "__init__.py").is_file():
        sys.exit(f"install_python_ext: {package} is not a Python package (no __init__.py)")
    site = Path(sysconfig.get_paths()["purelib"])
    suffix = sysconfig.get_config_var("EXT_SUFFIX")
    # An editable install by `maturin develop` in this environment: its .pth and metadata.
    for leftover in [*site.glob("dvnav-*.dist-info"), *site.glob("dvnav.pth"), *site.glob("_dvnav*.pth")]:
        if leftover.is_dir():
            shutil.rmtree(leftover)
        else:
            leftover.unlink()
    target = site / package.name
    if target.exists():
        shutil.rmtree(target)
    shutil.copytree(package, target, ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    shutil.copy2(ext, target / f"_core{suffix}")
    print(f"install_python_ext: {package.name} with {ext} -> {target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
