"""The one typed config loader: a TOML/YAML file (or mapping) -> a frozen config dataclass; unknown keys refused.

Each layer keeps its own config dataclass and its own value rules (``measure.pipeline.MeasureConfig``,
``stereo_recon.reconstruct.ReconstructConfig``); this module only reads the file and checks the keys, so
every config file of the project fails the same way: one line naming the file and the key.
"""

from __future__ import annotations

import os
from dataclasses import fields
from pathlib import Path
from typing import Any

from stereo_recon.core.errors import ConfigError

SUFFIXES = (".toml", ".yaml", ".yml")


def read_config_file(path: str | os.PathLike) -> dict:
    """The mapping in a .toml/.yaml/.yml file; ConfigError (one line, naming the file) when missing or unparsable."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: config file not found")
    try:
        if p.suffix.lower() == ".toml":
            import tomllib

            data = tomllib.loads(p.read_text())
        elif p.suffix.lower() in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(p.read_text()) or {}
        else:
            raise ConfigError(f"{p}: config must be .toml, .yaml or .yml")
    except ConfigError:
        raise
    except Exception as err:
        raise ConfigError(f"{p}: cannot parse config ({' '.join(str(err).split())[:160]})") from None
    return data


def known_keys(data: Any, cls: type, where: str, what: str, section: str | None = None) -> dict:
    """``data`` checked against the fields of dataclass ``cls``: a mapping with no unknown key (else ConfigError).

    section: a table name the fields may sit under (``[measure]``), taken when it is the mapping's only key.
    where: the file (or option) named in errors; what: what the fields are, e.g. "measure parameters".
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping of {what}, got {type(data).__name__}")
    if section is not None and section in data and isinstance(data[section], dict) and len(data) == 1:
        data = data[section]
    known = [f.name for f in fields(cls)]
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)} (known: {', '.join(known)})")
    return data
