"""The project's exception classes: what a user did wrong, said in one line."""

from __future__ import annotations


class StereoReconError(Exception):
    """A user-facing error: the CLI prints ``str(err)`` on one line and exits non-zero.

    Messages should name the file (or option) and the problem, e.g.
    ``"cloud.ply: file has 0 points"``.
    """

    exit_code: int = 2


class InputError(StereoReconError):
    """Unreadable, missing, corrupt or unsuitable input (file or option)."""


class ConfigError(StereoReconError):
    """A config file or option value that cannot be used (unknown key, bad value)."""


class StageError(StereoReconError):
    """A pipeline stage could not produce its result from valid input (e.g. tracking lost, no truck found)."""

    def __init__(self, stage: str, message: str):
        super().__init__(f"{stage}: {message}")
        self.stage = stage
