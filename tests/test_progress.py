"""Progress on long runs (issue 42 item 5): a command that runs few tasks shows a bar of each run's
steps instead of a bar of tasks (a long building run sat at ``0/1``); many tasks keep the task bar."""

import importlib
import io
import sys

import pytest

import onlinemap.sweeps.engines as engines
from onlinemap import progress
from onlinemap.cli import main


class Terminal(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture
def bars(monkeypatch):
    """The bars the engine and the exploration loop make, with progress forced on
    (ONLINEMAP_PROGRESS=1; each test makes stderr a terminal: pytest's capture replaces a
    fixture's stderr when the test starts)."""
    made = []

    class Recording(progress.tqdm):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.shown = not self.disable  # close() sets disable
            made.append(self)

    monkeypatch.setenv(progress.PROGRESS_ENV, "1")
    monkeypatch.setattr(engines, "tqdm", Recording)
    monkeypatch.setattr(importlib.import_module("policies.explore"), "tqdm", Recording)
    return made


def shown(made):
    return [(bar.desc, bar.total, bar.n) for bar in made if bar.shown]


def test_one_run_counts_its_steps(bars, monkeypatch):
    monkeypatch.setattr(sys, "stderr", Terminal())
    assert main(["explore", "--world", "building:10x10,seed=2", "--planner", "frontier", "--steps", "40"]) == 0
    assert shown(bars) == [("explore (FrontierExplorer, rbpf)", 40, 40)]
    assert "/40 [" in sys.stderr.getvalue() and "/1 [" not in sys.stderr.getvalue()  # drawn: steps, not tasks


def test_navigate_with_two_runs_counts_steps(bars, monkeypatch):
    monkeypatch.setattr(sys, "stderr", Terminal())
    assert main(["navigate", "--world", "door,blocking=1,footprint=cross", "--goal", "2,2", "--planner", "goto",
                 "--repeats", "2", "--steps", "30"]) == 0
    runs = shown(bars)
    assert len(runs) == 2 and all(desc.startswith("explore (GoTo") and total == 31 for desc, total, _ in runs)


def test_many_tasks_count_tasks(bars, monkeypatch):
    monkeypatch.setattr(sys, "stderr", Terminal())
    assert main(["explore", "--world", "building:10x10,seed=2", "--planner", "frontier,random,sweep",
                 "--steps", "20"]) == 0
    assert shown(bars) == [("sweep explore", 3, 3)]


def test_counting_steps_is_scoped():
    assert not progress.step_bars()
    with progress.counting_steps():
        assert progress.step_bars()
        with progress.counting_steps(False):
            assert not progress.step_bars()
        assert progress.step_bars()
    assert not progress.step_bars()
