"""``onlinemap track`` end to end through real pipes: output equals the in-process estimator's
beliefs (to the last bit, via JSON's exact float repr), malformed lines are reported on stderr and
change nothing, and a killed process restarts from its last checkpoint."""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import onlinemap as om
from onlinemap import checkpoint as checkpoint_module
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


def test_signals_during_the_final_save_keep_every_printed_step(tmp_path):
    """Regression (issue 14 item 3): SIGTERM during the final save, or a second Ctrl-C, left a
    traceback, no checkpoint, and printed steps missing from the saved state. Here a stream of
    SIGTERM and SIGINT hits the process from the end of its input until it exits: no traceback,
    every stderr line is JSON, and the checkpoint holds every printed step."""
    world = "corridor:16"  # exact state 16 x 2**16 floats (8 MB): a save takes a while
    ck = tmp_path / "ck.npz"
    proc = subprocess.Popen([sys.executable, "-m", "onlinemap", "track", "--world", world, "--estimator", "exact",
                             "--checkpoint", str(ck), "--every", "1000"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    printed = []
    for t in range(6):
        proc.stdin.write(json.dumps({"observation": t % 2, **({"action": 1} if t else {})}) + "\n")
        proc.stdin.flush()
        printed.append(json.loads(proc.stdout.readline())["t"])
    proc.stdin.close()  # end of input: the final save starts
    sent = 0
    while proc.poll() is None:
        proc.send_signal((signal.SIGTERM, signal.SIGINT)[sent % 2])
        sent += 1
        time.sleep(0.001)
    err = proc.stderr.read()
    assert "Traceback" not in err, err
    events = [json.loads(line) for line in err.splitlines()]
    assert proc.returncode in (0, 130), (proc.returncode, events)
    assert {"event": "checkpoint", "t": printed[-1], "path": str(ck)} in events
    assert sent >= 1 and om.load(ck).t == printed[-1] == 5


def test_sigint_twice_while_stepping(tmp_path):
    """Two Ctrl-C while the process waits for input: one clean stop, the state saved once."""
    model = parse_world(WORLD).model
    run = random_run(model, 4, seed=1)
    ck = tmp_path / "ck.npz"
    proc = subprocess.Popen(command("exact", [], "--checkpoint", str(ck)), stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in lines_of(model, run):
        proc.stdin.write(line + "\n")
        proc.stdin.flush()
        proc.stdout.readline()
    proc.send_signal(signal.SIGINT)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "Traceback" not in err, err
    events = [json.loads(line) for line in err.splitlines()]
    assert [e["event"] for e in events if "event" in e] == ["start", "checkpoint", "stopped"]
    assert om.load(ck).t == 3


def test_hostile_lines_are_refused_one_by_one(monkeypatch, capsys):
    """Regression (issue 14 item 6): 1000 nested arrays raised an uncaught RecursionError and the
    rest of the input was lost; a huge line was held in memory and echoed whole."""
    huge = json.dumps({"observation": "x" * 200_000})
    text = "\n".join(["[" * 1000 + "]" * 1000, huge, '{"observation": 0}', "\xff", '{"action": 1, "observation": 1}'])
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(text.encode("utf-8", "surrogateescape")
                                                                  .replace(b"\xc3\xbf", b"\xff"))))
    assert main(["track", "--world", WORLD, "--estimator", "exact"]) == 0
    out, err = capsys.readouterr()
    assert [json.loads(line)["t"] for line in out.splitlines()] == [0, 1]
    errors = [json.loads(line) for line in err.splitlines() if '"error"' in line]
    assert [(e["line"], e["error"]) for e in errors] == [(1, "MalformedLineError"), (2, "MalformedLineError"),
                                                         (4, "MalformedLineError")]
    assert "1000 brackets" in errors[0]["message"] and "longer than 65536" in errors[1]["message"]
    assert "UTF-8" in errors[2]["message"]
    assert max(len(line) for line in err.splitlines()) < 1000  # nothing echoed whole


def test_long_value_is_quoted_as_an_excerpt(monkeypatch, capsys):
    text = json.dumps({"observation": "y" * 30_000}) + "\n"
    assert track_in_process(monkeypatch, [], text) == 0
    err = capsys.readouterr().err
    assert "InvalidObservationError" in err and "characters)" in err and len(err) < 2000


def test_closed_stdout_saves_every_delivered_step_and_no_other(tmp_path):
    """Regression (issue 14 item 6, issue 24 item 7): ``| head -1``: exit quietly; the checkpoint
    holds every step written to the pipe and none whose output could not be written. (Issue 24:
    no checkpoint was written at all, although step 0 was delivered.)"""
    ck = tmp_path / "ck.npz"
    model = parse_world(WORLD).model
    run = random_run(model, 3000, seed=5)
    shell = (f"{sys.executable} -m onlinemap track --world {WORLD} --estimator exact --checkpoint {ck} --every 700 "
             f"| head -1")
    done = subprocess.run(["bash", "-o", "pipefail", "-c", shell], input="\n".join(lines_of(model, run)) + "\n",
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and "Traceback" not in done.stderr and "Exception" not in done.stderr, done.stderr
    assert json.loads(done.stdout)["t"] == 0
    events = [json.loads(line) for line in done.stderr.splitlines()]
    (closed,) = [e for e in events if e.get("event") == "stdout closed"]
    assert closed["undelivered"] == 1  # the step whose output met the closed pipe
    assert [e["t"] for e in events if e.get("event") == "checkpoint"][-1] == closed["t"] >= 0
    saved = om.load(ck)  # exactly the state after the delivered steps, bit for bit
    assert saved.t == closed["t"]
    want = reference("exact", [], random_run(model, 3000, seed=5))[closed["t"]]
    assert json.loads(json.dumps(summarize(saved.belief, full=True))) == want


def test_unwritable_checkpoint_is_refused_at_start(tmp_path, monkeypatch, capsys):
    """Regression (issue 14 item 4): the first save failed after steps were processed, with a
    double traceback. Now: one error line at start-up, exit 2, nothing read."""
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert track_in_process(monkeypatch, ["--checkpoint", str(blocker / "ck.npz")], '{"observation": 0}\n') == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "cannot write checkpoint" in err


def test_failed_save_reports_one_line_and_keeps_the_previous_file(tmp_path, monkeypatch, capsys):
    """A full disk at the second save: one JSON error line, the first checkpoint kept, the loop goes
    on; the final save succeeds once space is back."""
    ck = tmp_path / "ck.npz"
    real_savez, calls = np.savez, []

    def flaky(file, **entries):
        calls.append(1)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        real_savez(file, **entries)

    monkeypatch.setattr(checkpoint_module.np, "savez", flaky)
    text = "".join(json.dumps({"observation": 0, **({"action": 1} if t else {})}) + "\n" for t in range(5))
    assert track_in_process(monkeypatch, ["--checkpoint", str(ck), "--every", "2"], text) == 0
    out, err = capsys.readouterr()
    assert [json.loads(line)["t"] for line in out.splitlines()] == [0, 1, 2, 3, 4]
    lines = [json.loads(line) for line in err.splitlines()]
    failures = [e for e in lines if e.get("error") == "CheckpointError"]
    assert len(failures) == 1 and failures[0]["t"] == 3 and "No space left" in failures[0]["message"]
    assert [e["t"] for e in lines if e.get("event") == "checkpoint"] == [1, 4]
    assert om.load(ck).t == 4


def test_start_event_gives_the_footprint_in_reading_order_and_a_list_gets_a_hint(monkeypatch, capsys):
    """Regression (issue 24 item 14): the start event did not say in which order an observation
    lists its readings, and a list observation on a one-cell sensor said only 'int index'."""
    monkeypatch.setattr(sys, "stdin", io.StringIO('{"observation": ["free", "wall", "free", "free", "wall"]}\n'))
    assert main(["track", "--world", "door,footprint=cross", "--estimator", "bk"]) == 0
    start = json.loads(capsys.readouterr().err.splitlines()[0])
    model = parse_world("door,footprint=cross").model
    assert start["footprint"] == [[0, 0], [-1, 0], [0, 1], [1, 0], [0, -1]] == [list(o) for o in model.footprint]
    assert track_in_process(monkeypatch, [], '{"observation": [0]}\n') == 0
    start, error = [json.loads(line) for line in capsys.readouterr().err.splitlines()]
    assert start["footprint"] == [[0, 0]]
    assert error["error"] == "InvalidObservationError" and "footprint=cross" in error["message"]


def test_temporaries_of_a_killed_save_are_removed_at_start(tmp_path, monkeypatch, capsys):
    """Regression (issue 24 item 7): ``kill -9`` during a save left ``.NAME.*.tmp`` files that piled
    up over restarts. Only this checkpoint's are removed: another process may be saving beside it.
    Issue 43 item 12: the clean-up deleted files it did not write, ``.ck.npz.bak.<x>.tmp`` (the
    temporary of a second tracker, saving ``ck.npz.bak``) and a user's ``.ck.npz.my-notes.tmp``;
    it matches exactly the names the atomic writer makes, of writers that are gone."""
    from estimator_cases import dead_pid

    ck, gone = tmp_path / "ck.npz", dead_pid()
    mine = [tmp_path / f".ck.npz.{gone}-0a1b2c3d.tmp", tmp_path / f".ck.npz.{gone}-ffffffff.tmp"]
    others = [tmp_path / f".other.npz.{gone}-0a1b2c3d.tmp", tmp_path / "ck.npz.notes.tmp",
              tmp_path / f".ck.npz.bak.{gone}-0a1b2c3d.tmp", tmp_path / ".ck.npz.my-notes.tmp",
              tmp_path / ".ck.npz.k1l2m3.tmp", tmp_path / f".ck.npz.{os.getpid()}-0a1b2c3d.tmp",  # a live writer's
              tmp_path / f".ck.npz.{gone}-0a1b2c3d.tmp.tmp", tmp_path / f".ck.npz.{gone}-0A1B2C3D.tmp"]
    for path in mine + others:
        path.write_bytes(b"half a file")
    assert track_in_process(monkeypatch, ["--checkpoint", str(ck)], '{"observation": 0}\n') == 0
    assert not any(path.exists() for path in mine) and all(path.exists() for path in others)
    events = [json.loads(line) for line in capsys.readouterr().err.splitlines()]
    assert events[0] == {"event": "removed temporaries", "count": 2, "path": str(ck)}
    assert track_in_process(monkeypatch, ["--checkpoint", str(ck)], "") == 0  # nothing left: no event
    assert json.loads(capsys.readouterr().err.splitlines()[0])["event"] == "resume"


SIGNAL_AT_START = """\
import os, signal, sys
import onlinemap.cli.track as track
real = track.{where}

def interrupted(*args, **kwargs):  # the signal arrives while the process starts up
    os.kill(os.getpid(), signal.{signal})
    return real(*args, **kwargs)

track.{where} = interrupted
from onlinemap.cli import main
sys.exit(main({argv!r}))
"""


@pytest.mark.parametrize("where", ["make_estimator", "load"])
@pytest.mark.parametrize("number, status", [(signal.SIGTERM, 0), (signal.SIGINT, 130)], ids=["SIGTERM", "SIGINT"])
def test_a_signal_during_start_up_stops_cleanly(tmp_path, where, number, status):
    """Regression (issue 24 item 7): SIGINT while building the estimator or resuming printed a
    traceback (or one non-JSON line) and SIGTERM killed the process without a word."""
    ck = tmp_path / "ck.npz"
    om.save(om.make_estimator("exact", parse_world(WORLD).model), ck)  # resumed: `load` runs at start-up
    argv = ["track", "--world", WORLD, "--estimator", "exact", "--checkpoint", str(ck)]
    code = SIGNAL_AT_START.format(where=where, signal=signal.Signals(number).name, argv=argv)
    done = subprocess.run([sys.executable, "-c", code], input='{"observation": 0}\n', capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == status and done.stdout == "", done.stderr  # no line read
    events = [json.loads(line) for line in done.stderr.splitlines()]
    assert [e["event"] for e in events] == ["resume", "stopped"]
    assert events[-1] == {"event": "stopped", "signal": signal.Signals(number).name, "t": -1}


def test_action_errors_speak_of_lines_and_unknown_or_repeated_keys_are_refused(monkeypatch, capsys):
    """Regression (issue 24 item 18): the first-step error spoke Python ("call step(None, z0)"); a
    key the protocol does not have (a robot's timestamp) or a key given twice must refuse the
    line, change nothing, and not echo the value."""
    lines = ['{"action": 1, "observation": 0}', '{"observation": 0, "timestamp": 1700000000.25}',
             '{"observation": 0, "observation": 1}', '{"observation": 0}', '{"observation": 1}',
             '{"action": 1, "observation": 1, "stamp": "' + "9" * 5000 + '"}', '{"action": 1, "observation": 1}']
    assert track_in_process(monkeypatch, [], "\n".join(lines) + "\n") == 0
    out, err = capsys.readouterr()
    assert [json.loads(line)["t"] for line in out.splitlines()] == [0, 1]
    errors = [json.loads(line) for line in err.splitlines()[1:]]
    assert [(e["line"], e["error"]) for e in errors] == [
        (1, "InvalidActionError"), (2, "MalformedLineError"), (3, "MalformedLineError"), (5, "InvalidActionError"),
        (6, "MalformedLineError")]
    first, timestamp, twice, missing, long_key = (e["message"] for e in errors)
    assert "step(" not in first and "z0" not in first and '{"observation": Z}' in first
    assert "'timestamp'" in timestamp and "1700000000" not in timestamp
    assert "'observation' given twice" in twice
    assert 'needs an action' in missing and '"action"' in missing and "step(" not in missing
    assert "'stamp'" in long_key and len(long_key) < 200
    reference_est = om.make_estimator("exact", parse_world(WORLD).model)  # the refused lines changed nothing
    reference_est.step(None, 0)
    assert json.loads(out.splitlines()[1]) == json.loads(json.dumps(summarize(reference_est.step(1, 1))))


def test_track_reports_a_stall_once_with_its_step(monkeypatch, capsys):
    # dead reckoning in a static corridor, pressing left at the start (cell 0, the left end): the belief
    # stays as it was at every step, so the third unchanged step (t = 3) is a stall, reported once
    lines = ['{"observation": 0}'] + ['{"action": "left", "observation": 0}'] * 6
    monkeypatch.setattr(sys, "stdin", io.StringIO("\n".join(lines) + "\n"))
    assert main(["track", "--world", "corridor:6", "--estimator", "dead_reckoning", "--stall-after", "3"]) == 0
    events = [json.loads(line) for line in capsys.readouterr().err.splitlines()]
    assert [e for e in events if e.get("event") == "stalled"] == [{"event": "stalled", "t": 3, "unchanged_steps": 3}]
    assert track_in_process(monkeypatch, ["--stall-after", "-1"]) == 2
    assert "--stall-after N needs N >= 0" in capsys.readouterr().err
