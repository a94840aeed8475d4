"""measurement.json's JSON Schema (measure/schemas/measurement.schema.json) and a validator for it."""

from __future__ import annotations

import functools
import json
from importlib import resources
from typing import Any

from stereo_recon.core.paths import RunPaths

SCHEMA_FILE = "measurement.schema.json"


@functools.lru_cache(maxsize=1)
def measurement_schema() -> dict:
    """The JSON Schema (draft 2020-12) of measurement.json, shipped as package data."""
    return json.loads(resources.files("measure").joinpath("schemas", SCHEMA_FILE).read_text(encoding="utf-8"))


class MeasurementSchemaError(ValueError):
    """A measurement record that breaks the schema; the message names the JSON path and the rule."""


def validate_measurement(record: dict[str, Any]) -> None:
    """Raise :class:`MeasurementSchemaError` ('at /verdict/overall: ...') when ``record`` breaks the schema."""
    import jsonschema

    schema = measurement_schema()
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)
    error = jsonschema.exceptions.best_match(cls(schema).iter_errors(record))
    if error is not None:
        where = "/" + "/".join(str(p) for p in error.absolute_path)
        raise MeasurementSchemaError(f"measurement.json at {where}: {error.message}")


def read_measurement(path) -> dict:
    """Read a measurement.json (or the one in an output folder) and validate it; MeasurementSchemaError if it breaks the schema."""
    from pathlib import Path

    path = Path(path)
    if path.is_dir():
        path = RunPaths(path).measurement
    record = json.loads(path.read_text(encoding="utf-8"))
    validate_measurement(record)
    return record
