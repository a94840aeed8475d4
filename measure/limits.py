"""Over-limit verdicts: compare measured truck dimensions with a regulation table.

Regulation tables are data files (TOML; a user's own table may also be YAML or JSON) with
this schema (unknown keys are rejected)::

    name = "cn-2016-62"                 # short identifier
    title = "..."                       # the regulation's full title
    source = "..."                      # where the numbers come from (order, article, standard)
    default_class = "any"               # class used when the caller names none
    notes = "..."                       # optional
    url = "..."                         # optional

    [classes.any]                       # one table per vehicle class
    description = "..."                 # optional
    length_m = 18.1                     # each limit optional (absent = no limit), > 0, metres
    width_m = 2.55
    height_m = 4.0
    citation = "..."                    # optional: the article/clause behind this class

A dimension is *over* its limit when even the low end of the measurement's uncertainty
interval exceeds it, *within* when even the high end does not, and *undecided* otherwise.
"""

from __future__ import annotations

import logging
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

from stereo_recon.core.config import read_table_file
from stereo_recon.core.errors import ConfigError, InputError

log = logging.getLogger(__name__)

DEFAULT_REGULATION = "cn-2016-62"
DIMENSIONS = ("length", "width", "height")
# A "truck" shorter than this cannot be a road goods vehicle: it is a scale model (the
# paper's trucks are 1:16-ish models) and gets no legal verdict unless a scale is given.
MIN_ROAD_VEHICLE_LENGTH_M = 4.0

_TOP_KEYS_REQUIRED = ("name", "title", "source", "default_class", "classes")
_TOP_KEYS_OPTIONAL = ("notes", "url")
_CLASS_LIMIT_KEYS = tuple(f"{d}_m" for d in DIMENSIONS)
_CLASS_TEXT_KEYS = ("description", "citation")
_SUFFIXES = (".toml", ".yaml", ".yml", ".json")


@dataclass(frozen=True)
class Regulation:
    """One regulation table: limits in metres per vehicle class."""

    name: str
    title: str
    source: str
    # class name -> {"length": m, "width": m, "height": m}; an absent key means no limit
    classes: dict[str, dict[str, float]]
    default_class: str
    # class name -> human description / legal citation (may be empty strings)
    class_descriptions: dict[str, str] = field(default_factory=dict)
    class_citations: dict[str, str] = field(default_factory=dict)
    notes: str = ""
    url: str = ""
    path: str = ""  # file it was read from

    def limits(self, vehicle_class: str | None = None) -> dict[str, float | None]:
        """Limits (metres, None = no limit) for ``vehicle_class`` (default class when None)."""
        cls = self._check_class(vehicle_class)
        lims = self.classes[cls]
        return {d: lims.get(d) for d in DIMENSIONS}

    def _check_class(self, vehicle_class: str | None) -> str:
        cls = self.default_class if vehicle_class is None else vehicle_class
        if cls not in self.classes:
            raise ConfigError(
                f"regulation {self.name}: unknown vehicle class {cls!r}; valid classes: {', '.join(sorted(self.classes))}"
            )
        return cls


def _builtin_dir():
    return resources.files("measure.regulations")


def list_regulations() -> list[str]:
    """Names of the built-in regulation tables (sorted)."""
    return sorted(p.name[: -len(".toml")] for p in _builtin_dir().iterdir() if p.name.endswith(".toml"))


def load_regulation(name_or_path: str | Path = DEFAULT_REGULATION) -> Regulation:
    """Load a built-in regulation by name, or a user's table from a .toml/.yaml/.yml/.json file.

    Raises ConfigError (naming the file and the key) for a missing file, a parse error or
    any schema violation.
    """
    text = str(name_or_path)
    builtins = list_regulations()
    if text in builtins:
        res = _builtin_dir().joinpath(f"{text}.toml")
        with res.open("rb") as f:
            data = tomllib.load(f)
        return _regulation_from_dict(data, f"{text}.toml (built-in)", path=str(res))
    path = Path(text)
    if path.suffix.lower() not in _SUFFIXES and not path.exists():
        raise ConfigError(
            f"unknown regulation {text!r}; built-in: {', '.join(builtins)}; or pass a table file ({'/'.join(_SUFFIXES)})"
        )
    if not path.is_file():
        raise ConfigError(f"{path}: regulation file not found")
    return _regulation_from_dict(_read_table(path), str(path), path=str(path))


def _read_table(path: Path) -> Any:
    return read_table_file(path, "regulation file", _SUFFIXES)


def _text(value: Any, where: str, key: str, *, required: bool = True) -> str:
    if value is None and not required:
        return ""
    if not isinstance(value, str) or (required and not value.strip()):
        raise ConfigError(f"{where}: key {key!r} must be a non-empty string")
    return value


def _regulation_from_dict(data: Any, where: str, path: str = "") -> Regulation:
    """Validate a parsed table strictly; ``where`` names the file in error messages."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: a regulation table must be a mapping with keys {', '.join(_TOP_KEYS_REQUIRED)}")
    unknown = sorted(set(data) - set(_TOP_KEYS_REQUIRED) - set(_TOP_KEYS_OPTIONAL))
    if unknown:
        raise ConfigError(
            f"{where}: unknown key {unknown[0]!r}; allowed: {', '.join(_TOP_KEYS_REQUIRED + _TOP_KEYS_OPTIONAL)}"
        )
    for key in _TOP_KEYS_REQUIRED:
        if key not in data:
            raise ConfigError(f"{where}: missing key {key!r}")
    name = _text(data["name"], where, "name")
    title = _text(data["title"], where, "title")
    source = _text(data["source"], where, "source")
    default_class = _text(data["default_class"], where, "default_class")
    notes = _text(data.get("notes"), where, "notes", required=False)
    url = _text(data.get("url"), where, "url", required=False)
    raw_classes = data["classes"]
    if not isinstance(raw_classes, Mapping) or not raw_classes:
        raise ConfigError(f"{where}: key 'classes' must be a non-empty table of vehicle classes")
    classes: dict[str, dict[str, float]] = {}
    descriptions: dict[str, str] = {}
    citations: dict[str, str] = {}
    for cls, entry in raw_classes.items():
        ckey = f"classes.{cls}"
        if not isinstance(cls, str) or not cls.strip():
            raise ConfigError(f"{where}: class names must be non-empty strings, got {cls!r}")
        if not isinstance(entry, Mapping):
            raise ConfigError(f"{where}: key {ckey!r} must be a table of limits")
        bad = sorted(set(entry) - set(_CLASS_LIMIT_KEYS) - set(_CLASS_TEXT_KEYS))
        if bad:
            raise ConfigError(
                f"{where}: unknown key '{ckey}.{bad[0]}'; allowed: {', '.join(_CLASS_LIMIT_KEYS + _CLASS_TEXT_KEYS)}"
            )
        lims: dict[str, float] = {}
        for dim in DIMENSIONS:
            key = f"{dim}_m"
            if key not in entry or entry[key] is None:
                continue
            v = entry[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ConfigError(f"{where}: key '{ckey}.{key}' must be a positive number of metres, got {v!r}")
            lims[dim] = float(v)
        classes[cls] = lims
        descriptions[cls] = _text(entry.get("description"), where, f"{ckey}.description", required=False)
        citations[cls] = _text(entry.get("citation"), where, f"{ckey}.citation", required=False)
    if default_class not in classes:
        raise ConfigError(
            f"{where}: key 'default_class' names class {default_class!r}, which is not in 'classes' ({', '.join(sorted(classes))})"
        )
    return Regulation(
        name=name, title=title, source=source, classes=classes, default_class=default_class,
        class_descriptions=descriptions, class_citations=citations, notes=notes, url=url, path=path,
    )


def _dim_value(d: Mapping[str, Any], dim: str) -> Any:
    # accept both {"length": ...} and {"length_m": ...}
    if dim in d:
        return d[dim]
    return d.get(f"{dim}_m")


def _as_float(v: Any, what: str) -> float:
    if v is None:
        return math.nan
    if isinstance(v, bool):
        raise InputError(f"{what} must be a number, got {v!r}")
    try:
        return float(v)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number, got {v!r}") from None


def _checked_factors(k_sigma: Any, scale: float | None) -> tuple[float, float]:
    """(k, s): the coverage factor (finite, >= 0) and the model-to-real factor (> 0; 1 without one)."""
    k = _as_float(k_sigma, "k_sigma")
    if not math.isfinite(k) or k < 0:
        raise ConfigError(f"k_sigma must be a finite number >= 0, got {k_sigma!r}")
    if scale is None:
        return k, 1.0
    s = _as_float(scale, "scale")
    if not math.isfinite(s) or s <= 0:
        raise ConfigError(f"scale must be a positive number (model-to-real factor), got {scale!r}")
    return k, s


def _dimension_verdict(v: float, u: float, lim: float | None, k: float) -> dict[str, Any]:
    """One dimension's entry: value v, standard uncertainty u and limit lim (m), its verdict at k sigma."""
    entry: dict[str, Any] = {
        "value_m": v if math.isfinite(v) else None,
        "uncertainty_m": u if math.isfinite(u) else None,
        "limit_m": lim,
        "margin_m": (lim - v) if (lim is not None and math.isfinite(v)) else None,
    }
    if lim is None:
        status = "no-limit"
    elif not math.isfinite(v):
        status = "not-measured"
    elif not math.isfinite(u):
        # without an uncertainty there is no interval to compare, so any verdict would be a guess
        status = "undecided"
    elif v - k * u > lim:
        status = "over"
    elif v + k * u <= lim:
        status = "within"
    else:
        status = "undecided"
    entry["verdict"] = status
    return entry


def _overall(statuses: list[str], regulation: Regulation, cls: str, k: float) -> tuple[str, str]:
    """(overall verdict, reason) from the per-dimension verdicts (in DIMENSIONS order)."""
    names = {"over": "over the limit", "undecided": "limit within the uncertainty", "not-measured": "not measured"}
    if "over" in statuses:
        overall = "over"
    elif "undecided" in statuses or "not-measured" in statuses:
        overall = "undecided"
    elif "within" in statuses:
        overall = "within"
    else:
        overall = "no-limit"
    flagged = [f"{d} {names[st]}" for d, st in zip(DIMENSIONS, statuses) if st in names]
    if overall == "within":
        return overall, f"all limited dimensions within {regulation.name} ({cls}) at {k:g} sigma"
    if overall == "no-limit":
        return overall, f"{regulation.name} ({cls}) sets no dimension limit"
    return overall, f"{'; '.join(flagged)} ({regulation.name}, {cls}, {k:g} sigma)"


def over_limit_verdict(
    dims_m: Mapping[str, float],
    uncertainty_m: Mapping[str, float],
    regulation: Regulation,
    vehicle_class: str | None = None,
    scale: float | None = None,
    k_sigma: float = 2.0,
) -> dict:
    """Verdict per dimension and overall for measured truck dimensions.

    dims_m: {"length", "width", "height"} in metres (keys with a ``_m`` suffix accepted too;
        a missing/None/NaN value is reported as ``not-measured``).
    uncertainty_m: one standard uncertainty per dimension, metres (missing/NaN: unknown).
    regulation: a table from :func:`load_regulation`.
    vehicle_class: class in the table; None uses the table's default class.
    scale: model-to-real factor; measured values and uncertainties are multiplied by it.
        Without it, a truck shorter than 4 m (a scale model) gets ``not-applicable``.
    k_sigma: coverage factor; the interval checked is value ± k_sigma·uncertainty.

    Per dimension: ``over`` if value − k·u > limit, ``within`` if value + k·u ≤ limit,
    ``undecided`` if the limit lies inside [value − k·u, value + k·u], ``no-limit`` when the
    class sets none. Overall: over if any over, else undecided if any undecided (or a limited
    dimension was not measured), else within. ``margin_m`` = limit − value (positive: headroom).
    """
    k, s = _checked_factors(k_sigma, scale)
    cls = regulation._check_class(vehicle_class)
    limits = regulation.limits(cls)

    out: dict[str, Any] = {
        "overall": None,
        "reason": "",
        "regulation": {
            "name": regulation.name,
            "title": regulation.title,
            "source": regulation.source,
            "notes": regulation.notes,
        },
        "vehicle_class": cls,
        "class_description": regulation.class_descriptions.get(cls, ""),
        "class_citation": regulation.class_citations.get(cls, ""),
        "class_is_default": vehicle_class is None,
        "k_sigma": k,
        "scale": None if scale is None else s,
        "dimensions": {},
    }

    measured = {d: _as_float(_dim_value(dims_m, d), f"dims_m[{d!r}]") for d in DIMENSIONS}
    uncert = {d: _as_float(_dim_value(uncertainty_m, d), f"uncertainty_m[{d!r}]") for d in DIMENSIONS}
    for d, u in uncert.items():
        if math.isfinite(u) and u < 0:
            raise InputError(f"uncertainty_m[{d!r}] must be >= 0, got {u!r}")
    for d in DIMENSIONS:
        out["dimensions"][d] = _dimension_verdict(measured[d] * s, uncert[d] * s, limits[d], k)
    statuses = [e["verdict"] for e in out["dimensions"].values()]

    length = measured["length"]
    if scale is None and math.isfinite(length) and length < MIN_ROAD_VEHICLE_LENGTH_M:
        out["overall"] = "not-applicable"
        out["reason"] = (
            f"measured length {length:.3f} m is below {MIN_ROAD_VEHICLE_LENGTH_M:g} m: a scale model, not a road "
            f"vehicle; no legal verdict (pass a model-to-real scale factor to apply {regulation.name})"
        )
        for entry in out["dimensions"].values():
            entry["verdict"] = "not-applicable"
            entry["margin_m"] = None  # a model's size against a road limit means nothing
        return out
    out["overall"], out["reason"] = _overall(statuses, regulation, cls, k)
    log.debug("verdict %s: %s", out["overall"], out["reason"])
    return out


def regulations_help() -> str:
    """Human-readable list of the built-in regulations, their classes and limits (for ``--help`` / listing)."""
    lines = []
    for name in list_regulations():
        reg = load_regulation(name)
        lines.append(f"{name}: {reg.title}")
        lines.append(f"  source: {reg.source}")
        for cls, lims in reg.classes.items():
            txt = ", ".join(f"{d} {lims[d]:g} m" if d in lims else f"{d} no limit" for d in DIMENSIONS)
            default = " (default)" if cls == reg.default_class else ""
            lines.append(f"  {cls}{default}: {txt}")
    return "\n".join(lines)
