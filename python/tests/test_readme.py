"""The README's Python examples, run as a user would paste them."""

import re
import subprocess
import sys

from conftest import ROOT


def example(name: str) -> str:
    text = (ROOT / "README.md").read_text()
    m = re.search(rf"<!-- example: {name} -->\s*```python\n(.*?)```", text, re.S)
    assert m, f"README.md has no `example: {name}` block"
    return m.group(1)


def run(code: str, cwd) -> str:
    done = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_the_loading_example_drives_the_shipped_agent_to_its_goal():
    out = run(example("policy"), ROOT)
    assert out.strip().splitlines()[-1] == "success"


def test_the_sb3_example_trains_and_saves(tmp_path):
    code = example("sb3")
    assert "total_timesteps=20_000" in code
    out = run(code.replace("total_timesteps=20_000", "total_timesteps=300"), tmp_path)
    assert (tmp_path / "sac-dvnav.zip").is_file()
    assert "total_timesteps" in out, "SB3 logged its progress"
