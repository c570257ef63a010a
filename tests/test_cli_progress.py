"""Progress of `dynfab run`: per-step lines always; within a step, a live status line
(time steps, residual against tolerance, time in the step) only when stderr is a terminal."""

import io
import os
import pty
import subprocess
import sys

from dynfab.compiling import MESSAGE
from test_cli_dynamic import SMALL


class Stream(io.StringIO):
    """A text stream that says whether it is a terminal."""

    def __init__(self, tty: bool) -> None:
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


STATUS = "dynamic: 2000 time steps, residual 0.001 N (tolerance 1e-06 N), 1 of 1 yarns running"


def test_live_line_is_overwritten_in_place_and_cleared_before_a_step_line():
    from dynfab.cli import _Progress

    stream = Stream(tty=True)
    progress = _Progress(stream)
    progress.status(STATUS)
    progress.status(STATUS.replace("2000", "4000"))
    progress.line("[1/3] load 0.3 N")
    text = stream.getvalue()
    assert text.count("\r") == 3 and "\n" not in text.replace("[1/3] load 0.3 N\n", "")
    assert "4000 time steps" in text and "step running 0 s: dynamic:" in text
    assert text.endswith("\r\x1b[K[1/3] load 0.3 N\n")


def test_a_study_s_live_line_is_shown_as_given_and_only_on_a_terminal():
    from dynfab.cli import _Progress

    line = "cases: 3 finished, 0 failed, 2 running, 5 waiting of 10; about 12 s left"
    terminal, pipe = Stream(tty=True), Stream(tty=False)
    for stream in (terminal, pipe):
        progress = _Progress(stream)
        progress.show(line)
        progress.show("")  # cleared
    assert terminal.getvalue() == "\r" + line + "\x1b[K" + "\r\x1b[K"
    assert pipe.getvalue() == ""


def test_no_live_line_when_stderr_is_not_a_terminal():
    from dynfab.cli import _Progress

    stream = Stream(tty=False)
    progress = _Progress(stream)
    progress.status(STATUS)
    progress.line("[1/3] load 0.3 N")
    assert stream.getvalue() == "[1/3] load 0.3 N\n"


def run_small(tmp_path, stderr):
    scene = tmp_path / "small.toml"
    scene.write_text(SMALL)
    return subprocess.run([sys.executable, "-m", "dynfab.cli", "run", str(scene), "--solver",
                           "dynamic", "--out", str(tmp_path / "small.h5")],
                          stdout=subprocess.DEVNULL, stderr=stderr, timeout=600)


def test_dynamic_run_on_a_terminal_shows_the_solver_status(tmp_path):
    """A real run with stderr on a pseudo-terminal: the solver's launches show up live."""
    master, slave = pty.openpty()
    try:
        done = run_small(tmp_path, slave)
        os.close(slave)
        chunks = []
        while True:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # the terminal closed: everything is read
                break
            if not chunk:
                break
            chunks.append(chunk)
    finally:
        os.close(master)
    text = b"".join(chunks).decode()
    assert done.returncode == 0, text
    assert "\r" in text and "step running" in text and "time steps, residual" in text
    assert "[3/3]" in text


def test_dynamic_run_into_a_pipe_has_step_lines_only(tmp_path):
    done = run_small(tmp_path, subprocess.PIPE)
    assert done.returncode == 0, done.stderr
    stderr = done.stderr.decode()
    assert "\r" not in stderr and "step running" not in stderr
    lines = stderr.splitlines()
    if lines[0] == MESSAGE:  # this run compiled the kernels (a cold cache): said first, once
        lines = lines[1:]
    assert [line[:5] for line in lines[:3]] == ["[1/3]", "[2/3]", "[3/3]"]
