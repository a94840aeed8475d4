"""On a terminal, what C libraries write to file descriptors 1/2 goes to the log, not onto the screen."""

from __future__ import annotations

import os
import pty
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

CHILD = r"""
import logging, os, sys
logging.basicConfig(filename=sys.argv[1], level=logging.DEBUG, format="%(name)s %(message)s")
from stereo_recon.core.progress import NativeOutputToLog
with NativeOutputToLog():
    os.write(2, b"[mjpeg @ 0x55] overread 8\n")      # as FFmpeg writes it, below Python
    os.write(1, b"[Open3D WARNING] something\n")
    print("result line", file=sys.stderr)            # Python's own output still reaches the terminal
print("after", flush=True)
"""


def test_native_library_output_goes_to_the_log_on_a_terminal(tmp_path):
    log = tmp_path / "log.txt"
    master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(log)], stdin=slave, stdout=slave, stderr=slave,
                            env=dict(os.environ, PYTHONPATH=str(REPO)), cwd=REPO)
    os.close(slave)
    screen = b""
    while True:
        try:
            chunk = os.read(master, 4096)
        except OSError:   # the child closed the terminal
            break
        if not chunk:
            break
        screen += chunk
    proc.wait(timeout=60)
    os.close(master)
    text = screen.decode("utf-8", "replace")
    assert proc.returncode == 0, text
    assert "result line" in text and "after" in text
    assert "overread" not in text and "Open3D WARNING" not in text
    logged = log.read_text()
    assert "stereo_recon.native [mjpeg @ 0x55] overread 8" in logged
    assert "stereo_recon.native [Open3D WARNING] something" in logged


def test_nothing_is_redirected_off_a_terminal(capfd):
    from stereo_recon.core.progress import NativeOutputToLog

    with NativeOutputToLog():   # pytest's captured stderr is not a terminal
        os.write(2, b"native line\n")
    assert "native line" in capfd.readouterr().err
