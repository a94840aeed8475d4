"""ReconstructConfig validation (terminal progress is tested in test_progress.py)."""

from __future__ import annotations

import pytest

from stereo_recon.core.errors import ConfigError
from stereo_recon.reconstruct import ReconstructConfig


def test_reconstruct_config_rejects_bad_values():
    with pytest.raises(ConfigError, match="--poses"):
        ReconstructConfig(poses="slam")
    with pytest.raises(ConfigError, match="depth range"):
        ReconstructConfig(depth_min_m=5.0, depth_max_m=2.0)
    with pytest.raises(ConfigError, match="--step"):
        ReconstructConfig(step=0)
    assert ReconstructConfig(poses="gt:/x/poses.txt").poses.startswith("gt:")
