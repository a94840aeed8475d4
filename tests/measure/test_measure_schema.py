"""measurement.json's JSON Schema: valid records pass, broken ones fail with the path named; the schema is package data."""

from __future__ import annotations

import copy
import json

import pytest

from measure.schema import MeasurementSchemaError, measurement_schema, validate_measurement
from measure.synthetic_cloud import MODEL_TRUCK, SceneSpec, make_truck_scene


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    from stereo_recon.core.cloud_io import write_cloud
    from measure.pipeline import measure_cloud_file

    pts, _ = make_truck_scene(MODEL_TRUCK, SceneSpec(spacing_m=0.01, noise_m=0.002), rng=5)
    d = tmp_path_factory.mktemp("schema")
    write_cloud(d / "truck.ply", pts)
    res = measure_cloud_file(d / "truck.ply", d / "out", scale=8.0, plots=False, html=False, case={"case_id": "A-1"})
    return json.loads((d / "out" / "measurement.json").read_text())


def test_a_written_measurement_validates_and_names_its_version(record):
    validate_measurement(record)
    assert record["schema_version"] == "1.0"
    # every top-level key the measure stage writes is documented in the schema
    assert set(record) <= set(measurement_schema()["properties"])


@pytest.mark.parametrize("path, value, where", [
    (("schema_version",), "2.0", "/schema_version"),
    (("verdict", "overall"), "maybe", "/verdict/overall"),
    (("uncertainty_m", "width"), "0.1", "/uncertainty_m/width"),
    (("input", "sha256"), "xyz", "/input/sha256"),
])
def test_broken_records_fail_naming_the_path(record, path, value, where):
    bad = copy.deepcopy(record)
    node = bad
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(MeasurementSchemaError, match=f"at {where}:"):
        validate_measurement(bad)


def test_data_quality_contract(record):
    ok = dict(record, data_quality={"ok": False, "checks": [{"name": "coverage", "status": "fail", "detail": "one side"}]})
    validate_measurement(ok)
    with pytest.raises(MeasurementSchemaError, match="/data_quality/checks/0/status"):
        validate_measurement(dict(record, data_quality={"ok": True, "checks": [{"name": "x", "status": "bad", "detail": ""}]}))
    with pytest.raises(MeasurementSchemaError, match="required"):
        validate_measurement({k: v for k, v in record.items() if k != "length_m"})
