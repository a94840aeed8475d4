"""The core layer: the one atomic writer and file transaction, the config key check, the side-by-side split."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from measure.pipeline import MeasureConfig
from stereo_recon.core.atomic import staged_files, write_atomic, write_json_atomic, write_text_atomic
from stereo_recon.core.config import known_keys
from stereo_recon.core.errors import ConfigError, InputError
from stereo_recon.core.frames import split_side_by_side
from stereo_recon.core.paths import RECONSTRUCTION_FILES, RUN_OUTPUTS, RunPaths


def test_write_atomic_gives_the_plain_open_mode_and_leaves_no_temp_on_failure(tmp_path):
    p = write_text_atomic(tmp_path / "a" / "x.txt", "hello\n")
    umask = os.umask(0)
    os.umask(umask)
    assert p.read_text() == "hello\n" and (p.stat().st_mode & 0o777) == 0o666 & ~umask
    write_json_atomic(tmp_path / "j.json", {"v": np.float64(1.5), "a": np.arange(2)})
    assert (tmp_path / "j.json").read_text() == '{\n  "v": 1.5,\n  "a": [\n    0,\n    1\n  ]\n}\n'

    def broken(tmp: str) -> None:
        open(tmp, "w").write("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        write_atomic(p, broken)
    assert p.read_text() == "hello\n" and sorted(f.name for f in p.parent.iterdir()) == ["x.txt"]


def test_staged_files_moves_all_or_nothing(tmp_path):
    with staged_files(tmp_path / "new" / "dir") as tx:
        tx.add(write_text_atomic(tx.temp("a.txt"), "a"), tmp_path / "new" / "dir" / "a.txt")
        tx.add(write_text_atomic(tx.temp("b.txt"), "b"), tmp_path / "elsewhere" / "b.txt")
    assert (tmp_path / "new" / "dir" / "a.txt").read_text() == "a" and (tmp_path / "elsewhere" / "b.txt").read_text() == "b"
    assert sorted(f.name for f in (tmp_path / "new" / "dir").iterdir()) == ["a.txt"]
    with pytest.raises(InputError):
        with staged_files(tmp_path / "made" / "here") as tx:
            tx.add(write_text_atomic(tx.temp("c.txt"), "c"), tmp_path / "made" / "here" / "c.txt")
            raise InputError("board not found")
    assert not (tmp_path / "made").exists()   # the folders it made are gone again


def test_unknown_config_key_is_one_line_naming_file_and_key():
    with pytest.raises(ConfigError, match=r"^m\.toml: unknown key\(s\) eps_mm \(known: resolution_m"):
        known_keys({"eps_mm": 0.1}, MeasureConfig, "m.toml", "measure parameters", section="measure")
    assert known_keys({"measure": {"eps_m": 0.1}}, MeasureConfig, "m.toml", "x", section="measure") == {"eps_m": 0.1}


def test_side_by_side_split_and_its_refusals():
    frame = np.zeros((720, 2560, 3), np.uint8)
    frame[:, 1280:] = 7
    left, right = split_side_by_side(frame)
    assert left.shape == right.shape == (720, 1280, 3) and right.min() == 7 and left.max() == 0
    with pytest.raises(InputError, match="odd"):
        split_side_by_side(np.zeros((10, 21), np.uint8), "x.png")
    with pytest.raises(InputError, match="not side-by-side"):
        split_side_by_side(np.zeros((720, 1280), np.uint8))
    assert split_side_by_side(np.zeros((720, 1280), np.uint8), check_aspect=False)[0].shape == (720, 640)


def test_run_paths_name_every_output():
    p = RunPaths(Path("/r"))
    assert {p.cloud.name, p.poses.name, p.run_json.name, p.mesh.name} == set(RECONSTRUCTION_FILES)
    assert {p.measurement.name, p.report.name, p.summary.name, p.keyframe.name, p.measure_run.name} <= RUN_OUTPUTS
