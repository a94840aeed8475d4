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


def read_table_file(path: str | os.PathLike, what: str = "config", suffixes: tuple[str, ...] = (".toml", ".yaml", ".yml")) -> Any:
    """The data in a .toml/.yaml/.yml (or, when listed in ``suffixes``, .json) file.

    what: what the file is, named in errors ("config", "regulation file"). Raises ConfigError (one line,
    naming the file) when it is missing, unreadable, not UTF-8, of another type or unparsable.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if not p.is_file():
        raise ConfigError(f"{p}: {what} not found")
    if suffix not in suffixes:
        raise ConfigError(f"{p}: {what} must be {', '.join(suffixes[:-1])} or {suffixes[-1]}")
    try:
        raw = p.read_text(encoding="utf-8")
    except OSError as err:
        raise ConfigError(f"{p}: cannot read {what} ({err.strerror or err})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: {what} is not UTF-8 text") from None
    try:
        if suffix == ".toml":
            import tomllib

            return tomllib.loads(raw)
        if suffix == ".json":
            import json

            return json.loads(raw)
        import yaml

        return yaml.safe_load(raw)
    except Exception as err:  # tomllib/json/yaml parse errors have no common base class
        raise ConfigError(f"{p}: cannot parse {what} ({' '.join(str(err).split())[:160]})") from None


def read_config_file(path: str | os.PathLike) -> dict:
    """The mapping in a .toml/.yaml/.yml config file (empty YAML: {}); ConfigError naming the file otherwise."""
    data = read_table_file(path, "config file")
    return {} if data is None else data


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
