"""The README, a front page, and the user guide's pages (``onlinemap/docs/pages/``): CI runs the
README's test command verbatim, the README stays short and its links resolve, and the guide's
examples give what they say."""

import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = ROOT / "onlinemap" / "docs" / "pages"


def python_blocks(path: Path) -> list[str]:
    """The ```python blocks of a markdown file."""
    return [b.split("```", 1)[0] for b in path.read_text().split("```python\n")[1:]]


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    block = readme.split("```bash\n", 1)[1].split("```", 1)[0].strip().splitlines()
    assert len(block) == 2, "the README opens with exactly two commands"
    assert "pytest" in block[1]
    assert block[1] in (ROOT / ".ci" / "run").read_text()


def test_the_readme_is_a_front_page():
    """At most about 200 lines; five tasks of 3-6 lines each; every local link and image it names
    exists (the animation may come later: its path is the one the docs site shows); no heading
    names an internal issue number."""
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 200
    start = readme.index("## Five things to try")
    tasks = readme[start:readme.index("\n## ", start)]  # up to the next section
    numbered = re.split(r"\n\*\*\d\. ", tasks)[1:]
    assert len(numbered) == 5
    for task in numbered:
        lines = sum(len(block.strip().splitlines()) for block in task.split("```")[1::2])
        assert 3 <= lines <= 6, task[:60]
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", readme):
        if "://" not in target:
            assert (ROOT / target).exists(), target
    assert not [line for line in readme.splitlines() if line.startswith("#") and re.search(r"issue \d", line)]


def test_the_guide_names_no_issue_numbers_in_headings():
    """Users read headings (the notebooks' included); the project's issue numbers mean nothing to them."""
    import nbformat

    texts = [page.read_text() for page in PAGES.rglob("*.md")]
    texts += [cell.source for path in (ROOT / "notebooks").glob("*.ipynb")  # rendered on the site too
              for cell in nbformat.read(path, as_version=4).cells if cell.cell_type == "markdown"]
    headings = [line for text in texts for line in text.splitlines()
                if line.startswith("#") and re.search(r"issue \d", line, re.IGNORECASE)]
    assert not headings


def test_the_readme_navigation_example_gives_what_it_says():
    """The README's navigation block prints the steps its comment gives (robot and oracle)."""
    (block,) = [b for b in python_blocks(ROOT / "README.md") if "policies.navigate(" in b]
    lines = block.strip().splitlines()
    namespace: dict = {}
    exec("\n".join(lines[:-1]), namespace)
    expression, expected = lines[-1].split("  # ")
    values = eval(expression.removeprefix("print(").removesuffix(")"), namespace)
    assert " ".join(str(v) for v in values) == expected.strip()
    run = namespace["run"]  # the robot stands on the goal at the step it says, and not before
    assert run.reached_at is not None and list(run.frame["distance_to_goal"])[-1] == 0


@pytest.mark.slow  # two closed loops of 300 steps
def test_the_readme_building_example_prints_what_it_says(capsys):
    """The "Mapping a building from nothing" block prints, run by run, the numbers the sentence
    after it gives; and the first number of each line is the run's final map error computed here by
    hand (1 - P(true label), averaged over the cells)."""
    readme = (ROOT / "README.md").read_text()
    (block,) = [b for b in python_blocks(ROOT / "README.md") if 'label_prior=prior' in b]
    namespace: dict = {}
    exec(block.replace("steps=300, seed=0)", "steps=300, seed=0, progress=False)"), namespace)
    printed = capsys.readouterr().out.strip().splitlines()
    claimed = re.search(r"It prints `([^`]*)`, then `([^`]*)`", readme).groups()
    assert printed == list(claimed)
    last = namespace["run"]  # the learned prior's run
    final, truth = last.trajectory.map[-1], last.run.final_map
    by_hand = 1.0 - sum(final[i][truth[i]] for i in range(len(truth))) / len(truth)
    assert f"{by_hand:.2f}" == printed[-1].split()[0]


def test_the_guide_door_world_example_gives_what_it_says():
    """The door-world block of the getting-started page runs and prints the values its comments give, and what
    they claim holds by hand: the most likely cell (an argmax written here) is the true one, the
    mean location error over steps 100-199 is 1 - P(true cell) averaged here, and the run's map
    has the one wrong cell the text says."""
    page = PAGES / "guide" / "getting-started.md"
    (block,) = [b for b in python_blocks(page) if "exploration_world(p_door=0.0," in b]
    lines = block.strip().splitlines()
    namespace: dict = {}
    exec("\n".join(line for line in lines if "#" not in line), namespace)
    claims = []
    for line in (line for line in lines if "  # " in line):
        expression, expected = line.split("  # ")
        value = eval(expression, namespace)
        assert f"{value:.2f}" == expected.strip() if isinstance(value, float) else \
            str(tuple(int(v) for v in value)) == expected.strip()
        claims.append(expected.strip())
    # What the two numbers claim, checked by hand rather than by the code that printed them.
    run, est, trajectory = namespace["run"], namespace["est"], namespace["trajectory"]
    model = run.model
    moves = {"north": (-1, 0), "east": (0, 1), "south": (1, 0), "west": (0, -1)}
    for t, action in enumerate(run.actions):  # the true path is a walk: stay, or one cell the action's way
        (row, col), (dr, dc) = divmod(int(run.locations[t]), model.cols), moves[model.action_names[action]]
        assert divmod(int(run.locations[t + 1]), model.cols) in {(row, col), (row + dr, col + dc)}
    np.testing.assert_array_equal(trajectory.location[-1], est.belief.location)
    final = est.belief.location  # "(61, 61)": the most likely cell is the true one
    most_likely = max(range(model.n_cells), key=lambda cell: final[cell])
    assert claims[0] == f"({most_likely}, {run.locations[-1]})" and most_likely == run.locations[-1]
    errors = [1.0 - trajectory.location[t][run.locations[t]] for t in range(100, run.n_steps)]
    assert claims[1] == f"{sum(errors) / len(errors):.2f}"  # "0.34": 1 - P(true cell), mean over steps 100-199
    assert "in the run above one cell's most likely label is wrong" in " ".join(page.read_text().split())
    labels = est.belief.map
    assert sum(max(range(model.n_labels), key=lambda k: labels[i][k]) != run.final_map[i]
               for i in range(model.n_cells)) == 1


def test_the_guide_gym_example_runs():
    """The robot-loop page shows the import that registers the gym id, and the id."""
    pytest.importorskip("gymnasium")
    (block,) = [b for b in python_blocks(PAGES / "guide" / "robot-loop.md") if "import onlinemap.envs" in b]
    namespace: dict = {}
    exec(block, namespace)
    assert namespace["env"].spec.id == "onlinemap/DoorWorld-v0" and namespace["truncated"] is False


def test_the_test_command_keeps_a_files_tests_on_one_worker_and_runs_each_notebook_alone():
    """The README's ``--dist loadgroup`` hands out work as tests/conftest.py's ``work_unit`` says:
    a file's tests (which share its module fixtures, e.g. the 128 explorations of the dynamic door
    world's two claims) go to one worker, the RBPF's files together; each re-executed notebook is a
    unit of its own."""
    from conftest import work_unit

    claims = "tests/test_explore.py::test_dynamic_door_world_entropy_planner_"
    assert work_unit(claims + "keeps_doors_up_to_date") == work_unit(claims + "spends_more_time_at_doors") \
        == "tests/test_explore.py"
    rerun = "tests/test_notebooks.py::test_stored_outputs_are_current[{}]"
    assert work_unit(rerun.format("em_mapping")) != work_unit(rerun.format("navigation"))
    assert work_unit("tests/test_notebooks.py::test_notebook_has_its_generators_cells[em_mapping]") \
        == "tests/test_notebooks.py"
    # without pytest-xdist the scheduler's hook is unknown to pytest: optional, or no test would run
    from conftest import pytest_xdist_make_scheduler

    assert pytest_xdist_make_scheduler.pytest_impl["optionalhook"]
    # the RBPF's files share its kernels, serial and threaded: one unit
    assert work_unit("tests/test_rbpf.py::test_known_location_equals_exact") \
        == work_unit("tests/test_rbpf_threads.py::test_threads_option") != work_unit("tests/test_bk.py::test_x")


def test_every_results_table_comes_with_the_command_that_reproduces_it():
    """The results page: each section holds its command (a code block naming `onlinemap` or a
    study) before its first table."""
    text = (PAGES / "results.md").read_text()
    sections = text.split("\n## ")[1:]
    assert len(sections) >= 10
    for section in sections:
        title, body = section.split("\n", 1)
        assert "|---" in body.replace(" ", "") or "| ---" in body, title
        before_table = body.split("\n|", 1)[0]
        commands = before_table.split("```")[1::2]
        assert commands and all("onlinemap" in c for c in commands), title


def test_the_results_pages_corridor_rows_are_current():
    """The deterministic rows of the results page's Murphy-corridor table (exact, dead reckoning,
    offline EM, BK) are what the study gives today, at the precision the page prints."""
    from onlinemap.scenarios import murphy_corridor
    from onlinemap.studies.corridor import CORRIDOR_ESTIMATORS, corridor_table

    text = (PAGES / "results.md").read_text()
    table = text[text.index("## Murphy's corridor"):].split("\n## ", 1)[0]
    stated = {cells[0]: cells[1:] for line in table.splitlines() if line.startswith("| ")
              for cells in [[c.strip() for c in line.strip("|").split("|")]]}
    names = ("exact", "dead_reckoning", "offline_em", "bk")
    frame, _ = corridor_table(murphy_corridor(), [e for e in CORRIDOR_ESTIMATORS if e[0] in names], progress=False)
    for row in frame.itertuples():
        error, wrong, low, final = stated[row.estimator]
        for value, text_value in ((row.final_map_error, error), (row.min_p_true_way_back, low), (row.final_p_true, final)):
            assert float(text_value) == pytest.approx(value, rel=0.01, abs=5e-4), (row.estimator, text_value, value)
        assert int(wrong) == row.wrong_visited
