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
    run(code.replace("total_timesteps=20_000", "total_timesteps=300"), tmp_path)
    assert (tmp_path / "sac-dvnav.zip").is_file()
    # The saved agent loads and acts in the environment it was trained on.
    out = run(
        "import gymnasium, dvnav\n"
        "from stable_baselines3 import SAC\n"
        "model = SAC.load('sac-dvnav')\n"
        "env = gymnasium.make('dvnav/Nav-v0', room='env0', seed=1)\n"
        "action, _ = model.predict(env.reset()[0], deterministic=True)\n"
        "print(action.shape, env.action_space.contains(action))\n",
        tmp_path,
    )
    assert out.strip() == "(2,) True", out
