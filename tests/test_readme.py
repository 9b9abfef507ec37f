"""The README's two commands: CI runs the test command verbatim."""

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    block = readme.split("```bash\n", 1)[1].split("```", 1)[0].strip().splitlines()
    assert len(block) == 2, "the README opens with exactly two commands"
    assert "pytest" in block[1]
    assert block[1] in (ROOT / ".ci" / "run").read_text()


def test_the_readme_door_world_example_gives_what_it_says():
    """The door-world block of the README runs and prints the values its comments give."""
    readme = (ROOT / "README.md").read_text()
    blocks = [b.split("```", 1)[0] for b in readme.split("```python\n")[1:]]
    (block,) = [b for b in blocks if "exploration_world(p_door=0.0," in b]
    lines = block.strip().splitlines()
    namespace: dict = {}
    exec("\n".join(line for line in lines if "#" not in line), namespace)
    for line in (line for line in lines if "  # " in line):
        expression, expected = line.split("  # ")
        value = eval(expression, namespace)
        assert f"{value:.2f}" == expected.strip() if isinstance(value, float) else \
            str(tuple(int(v) for v in value)) == expected.strip()


def test_the_readme_gym_example_runs():
    """Issue 24 item 18: the README shows the import that registers the gym id, and the id."""
    pytest.importorskip("gymnasium")
    readme = (ROOT / "README.md").read_text()
    (block,) = [b.split("```", 1)[0] for b in readme.split("```python\n")[1:] if "import onlinemap.envs" in b]
    namespace: dict = {}
    exec(block, namespace)
    assert namespace["env"].spec.id == "onlinemap/DoorWorld-v0" and namespace["truncated"] is False
