"""Terminal progress: one updating line per stage on a TTY, silent otherwise; config validation."""

from __future__ import annotations

import io

import pytest

from stereo_recon.errors import ConfigError
from stereo_recon.reconstruct import ReconstructConfig, TerminalProgress


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_on_tty_and_quiet_otherwise():
    tty = _Tty()
    p = TerminalProgress(stream=tty)
    for i in range(1, 4):
        p("depth", i, 3)
    p("fusion", 1, 2)
    p("fusion", 2, 2)
    p.close()
    text = tty.getvalue()
    assert "\rdepth: 3/3" in text and "\rfusion: 2/2" in text
    assert text.count("\n") == 2  # one finished line per stage
    plain = io.StringIO()  # not a terminal
    q = TerminalProgress(stream=plain)
    q("depth", 1, 3)
    q.close()
    assert plain.getvalue() == ""


def test_reconstruct_config_rejects_bad_values():
    with pytest.raises(ConfigError, match="--poses"):
        ReconstructConfig(poses="slam")
    with pytest.raises(ConfigError, match="depth range"):
        ReconstructConfig(depth_min_m=5.0, depth_max_m=2.0)
    with pytest.raises(ConfigError, match="--step"):
        ReconstructConfig(step=0)
    assert ReconstructConfig(poses="gt:/x/poses.txt").poses.startswith("gt:")
