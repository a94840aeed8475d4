"""Helpers of the bad-input tests: what a command left on disk, and its one-line refusal."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path


def folder_state(folder: Path) -> dict:
    """relative name -> sha256 of every file under ``folder``."""
    state = {}
    for root, _, files in os.walk(folder):
        for f in files:
            p = os.path.join(root, f)
            state[os.path.relpath(p, folder)] = hashlib.sha256(open(p, "rb").read()).hexdigest()
    return state


def no_temp_left(parent: Path) -> None:
    """No temporary, superseded or probe folder of a transaction remains in ``parent``."""
    assert not [p.name for p in Path(parent).iterdir() if ".tmp-" in p.name or ".old-" in p.name or "probe" in p.name]


def refused(capsys, argv, pattern: str) -> str:
    """Run the CLI; exit 2 with one error line (argparse may add its usage) holding ``pattern``, no traceback."""
    from stereo_recon.app.cli import main

    try:
        rc = main([str(a) for a in argv])
    except SystemExit as e:   # argparse's own refusals
        rc = e.code
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert "Traceback" not in err
    assert pattern in err, err
    assert len([line for line in err.splitlines() if not line.startswith(("usage:", " "))]) == 1, err
    return err
