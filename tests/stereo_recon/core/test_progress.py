"""Terminal progress (stereo_recon.core.progress): tqdm bars with k/N on a terminal, plain lines elsewhere, logs above bars."""

from __future__ import annotations

import io
import logging
import re

from stereo_recon.core.progress import ProgressConfig, StageProgress, TqdmLogHandler


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_tty_bars_show_stage_k_of_n_percent_and_eta():
    tty = _Tty()
    with StageProgress(("depth", "poses", "fusion"), stream=tty) as p:
        for i in range(1, 4):
            p("depth", i, 3)
        p("poses", 0, None)
        p("fusion", 1, 2)
        p("fusion", 2, 2)
    text = tty.getvalue()
    assert "[1/3] decode, rectify, depth + VO" in text and "100%" in text and "3/3" in text
    assert re.search(r"\[2/3\] poses: done in 00:0\d", text)
    assert "[3/3] TSDF fusion" in text and "2/2" in text
    # tqdm's rate on the first update is not the nonsense of a near-zero interval
    assert "1000000000" not in text


def test_plain_lines_when_not_a_terminal():
    out = io.StringIO()
    with StageProgress(("depth", "measure"), stream=out, config=ProgressConfig(plain_interval_s=0.0)) as p:
        p("depth", 0, 4)
        p("depth", 2, 4)
        p("depth", 4, 4)
        p("measure", 0, None)
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue()
    assert any(re.match(r"\[1/2\] decode, rectify, depth \+ VO: 2/4 frames  50% .*ETA", ln) for ln in lines)
    assert any(ln.startswith("[1/2] decode, rectify, depth + VO: done in") for ln in lines)
    assert lines[-1].startswith("[2/2] measure (ground, clusters, dimensions): done in")


def test_quiet_writes_nothing():
    out = _Tty()
    with StageProgress(stream=out, config=ProgressConfig(enabled=False)) as p:
        p("depth", 1, 3)
    assert out.getvalue() == ""


def test_log_lines_are_not_glued_to_the_bar():
    tty = _Tty()
    log = logging.getLogger("test_progress_glue")
    handler = TqdmLogHandler(tty)
    log.addHandler(handler)
    log.propagate = False
    try:
        with StageProgress(("depth",), stream=tty) as p:
            p("depth", 1, 10)
            log.warning("a message")
            p("depth", 2, 10)
    finally:
        log.removeHandler(handler)
    # the message sits on a line of its own (tqdm clears the bar, writes, redraws)
    assert re.search(r"(^|\n|\r)a message\n", tty.getvalue())


def test_a_failed_stage_leaves_no_done_line():
    out = io.StringIO()
    try:
        with StageProgress(("measure",), stream=out) as p:
            p("measure", 0, None)
            raise ValueError("bad input")
    except ValueError:
        pass
    assert out.getvalue() == ""  # a quick failure: the error message will be the only line
