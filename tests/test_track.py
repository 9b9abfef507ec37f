"""``onlinemap track`` end to end through real pipes: output equals the in-process estimator's
beliefs (to the last bit, via JSON's exact float repr), malformed lines are reported on stderr and
change nothing, and a killed process restarts from its last checkpoint."""

from __future__ import annotations

import io
import json
import signal
import subprocess
import sys

import numpy as np
import pytest

import onlinemap as om
from onlinemap.cli import main
from onlinemap.cli.track import parse_options, summarize
from onlinemap.worlds import parse_world
from estimator_cases import NAMES, beliefs, random_run

WORLD = "corridor:6,p_change=0.02"
SETUPS = [(name, options) for name, options in
          [("exact", []), ("rbpf", ["n_particles=40", "seed=3", "proposal=transition"])]
          if name in NAMES]


def command(name, options, *extra):
    args = [sys.executable, "-m", "onlinemap", "track", "--world", WORLD, "--estimator", name]
    for option in options:
        args += ["--option", option]
    return args + list(extra)


def lines_of(model, run):
    """The run as input lines, mixing indices and names."""
    lines = []
    for t in range(run.n_steps):
        z = int(run.observations[t])
        record = {"observation": z if t % 2 else model.label_names[z]}
        if t > 0:
            a = int(run.actions[t - 1])
            record["action"] = a if t % 3 else model.action_names[a]
        lines.append(json.dumps(record))
    return lines


MALFORMED = [  # (line, error type, words in the message)
    ("{not json", "MalformedLineError", "invalid JSON"),
    ('{"action": 1}', "MalformedLineError", "missing 'observation'"),
    ('{"action": 1, "observation": 0, "speed": 2}', "MalformedLineError", "unknown key(s) 'speed'"),
    ("[1, 0]", "MalformedLineError", "JSON object"),
    ('{"action": 9, "observation": 0}', "InvalidActionError", "out of range"),
    ('{"action": "up", "observation": 0}', "InvalidActionError", "unknown action name"),
    ('{"observation": 0}', "InvalidActionError", "needs an action"),
    ('{"action": 1, "observation": 2.5}', "InvalidObservationError", "whole number"),
    ('{"action": 1, "observation": [0]}', "InvalidObservationError", "int index"),
]


MALFORMED_FIRST = MALFORMED[:4] + [  # before the first step
    ('{"action": 1, "observation": 0}', "InvalidActionError", "first step takes no action"),
    ('{"observation": 7}', "InvalidObservationError", "out of range"),
]


def reference(name, options, run):
    est = om.make_estimator(name, parse_world(WORLD).model, **parse_options(options))
    return [json.loads(json.dumps(summarize(b, full=True))) for b in beliefs(est, run)]


@pytest.mark.parametrize("name,options", SETUPS, ids=[s[0] for s in SETUPS])
def test_track_through_a_pipe_with_bad_lines_and_a_restart(name, options, tmp_path):
    model = parse_world(WORLD).model
    run = random_run(model, 22, seed=11)
    lines, want = lines_of(model, run), reference(name, options, run)
    ck = tmp_path / "state" / "track.npz"
    args = command(name, options, "--checkpoint", str(ck), "--every", "4", "--full")

    # first process: steps 0..9 with bad lines in between; killed without warning after step 9
    first = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    got = []
    for t in range(10):
        for line, _, _ in {0: MALFORMED_FIRST, 5: MALFORMED}.get(t, []):
            first.stdin.write(line + "\n")
        first.stdin.write(lines[t] + "\n\n")  # blank lines are skipped
        first.stdin.flush()
        got.append(json.loads(first.stdout.readline()))
    first.kill()
    _, err = first.communicate(timeout=60)
    assert got == want[:10]
    events = [json.loads(line) for line in err.splitlines()]
    errors = [e for e in events if "error" in e]
    bad = MALFORMED_FIRST + MALFORMED
    assert [e["error"] for e in errors] == [m[1] for m in bad]
    assert all(m[2] in e["message"] for e, m in zip(errors, bad))
    assert [e["line"] for e in errors[:3]] == [1, 2, 3]
    assert [e["t"] for e in events if e.get("event") == "checkpoint"] == [3, 7]

    # restart: resumes after t = 7; the robot resends from step 8, then closes the pipe
    second = subprocess.run(args, input="\n".join(lines[8:]) + "\n", capture_output=True, text=True, timeout=120)
    assert second.returncode == 0, second.stderr
    events = [json.loads(line) for line in second.stderr.splitlines()]
    assert events[0]["event"] == "resume" and events[0]["t"] == 7
    assert events[-1] == {"event": "checkpoint", "t": run.n_steps - 1, "path": str(ck)}  # saved at the end
    assert [json.loads(line) for line in second.stdout.splitlines()] == want[8:]
    assert om.load(ck).t == run.n_steps - 1


def test_sigterm_saves_and_stops_between_steps(tmp_path):
    model = parse_world(WORLD).model
    run = random_run(model, 6, seed=2)
    ck = tmp_path / "ck.npz"
    proc = subprocess.Popen(command("exact", [], "--checkpoint", str(ck), "--every", "1000"), stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in lines_of(model, run):
        proc.stdin.write(line + "\n")
        proc.stdin.flush()
        assert json.loads(proc.stdout.readline())["t"] >= 0
    proc.send_signal(signal.SIGTERM)  # waiting for input: stops at once, saving first
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    events = [json.loads(line) for line in err.splitlines()]
    assert events[-2:] == [{"event": "checkpoint", "t": 5, "path": str(ck)},
                           {"event": "stopped", "signal": "SIGTERM", "t": 5}]
    assert om.load(ck).t == 5


def test_summary_without_full_and_options_parsing():
    assert parse_options(["window=max", "decay=0.9", "n=4", "anneal=[1, 0.5, 0.01]", "x=null"]) == \
        {"window": "max", "decay": 0.9, "n": 4, "anneal": (1, 0.5, 0.01), "x": None}
    model = om.corridor(3)
    b = om.make_estimator("dead_reckoning", model).step(None, 1)
    record = summarize(b)
    assert record == {"t": 0, "location": 0, "p_location": 1.0, "location_entropy": 0.0, "map": [0, 0, 0],
                      "map_entropy": 1.0, "log_evidence": None}
    assert np.isnan(b.log_evidence)


def track_in_process(monkeypatch, args, text=""):
    """Run ``onlinemap track`` in this process (faster than a subprocess) on ``text``."""
    monkeypatch.setattr(sys, "stdin", io.StringIO(text))
    return main(["track", "--world", WORLD, "--estimator", "exact"] + args)


def test_track_refuses_a_checkpoint_of_another_world_or_options(tmp_path, monkeypatch, capsys):
    ck = tmp_path / "ck.npz"
    assert track_in_process(monkeypatch, ["--checkpoint", str(ck)], '{"observation": 0}\n') == 0
    assert json.loads(capsys.readouterr().out)["t"] == 0
    for args, words in [(["--world", "corridor:5"], "another world ('cols'"),
                        (["--option", "max_bytes=1000000"], "options"),
                        (["--estimator", "dead_reckoning"], "holds a 'exact' estimator")]:
        assert track_in_process(monkeypatch, ["--checkpoint", str(ck)] + args) == 2
        assert words in capsys.readouterr().err
    ck.write_bytes(ck.read_bytes()[:100])  # a damaged checkpoint stops the process with a clear error
    assert track_in_process(monkeypatch, ["--checkpoint", str(ck)]) == 2
    assert "truncated or corrupt" in capsys.readouterr().err
    assert track_in_process(monkeypatch, ["--every", "3"]) == 2
    assert "--every K needs --checkpoint" in capsys.readouterr().err
    assert track_in_process(monkeypatch, ["--option", "colour=red"]) == 2
    assert "no option 'colour'" in capsys.readouterr().err
