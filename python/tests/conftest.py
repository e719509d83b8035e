"""Shared fixtures: the repository root and the dvnav binary (for parity with the Rust side)."""

import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "models" / "meta-r0.2"


@pytest.fixture(scope="session")
def root() -> Path:
    return ROOT


@pytest.fixture(scope="session")
def dvnav_bin() -> Path:
    """The `dvnav` command: $DVNAV_BIN (set by `make test-python`), else target/debug."""
    path = Path(os.environ.get("DVNAV_BIN", ROOT / "target" / "debug" / "dvnav"))
    if not path.is_file():
        subprocess.run(["cargo", "build", "--bin", "dvnav"], cwd=ROOT, check=True)
    return path
