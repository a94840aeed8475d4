"""Over-limit verdicts and regulation tables (measure/limits.py)."""

from __future__ import annotations

import json
import math

import pytest
import yaml

from measure.limits import (
    DEFAULT_REGULATION,
    list_regulations,
    load_regulation,
    over_limit_verdict,
    regulations_help,
)
from stereo_recon.core.errors import ConfigError, InputError

U0 = {"length": 0.0, "width": 0.0, "height": 0.0}


def _table(**over):
    base = {
        "name": "test-reg",
        "title": "A test regulation",
        "source": "tests/measure/test_measure_limits.py",
        "default_class": "truck",
        "classes": {
            "truck": {"length_m": 10.0, "width_m": 2.5, "height_m": 3.8, "description": "test truck"},
            "low": {"height_m": 3.0},
        },
    }
    base.update(over)
    return base


# --- built-in tables ----------------------------------------------------------------------

def test_builtin_tables_all_load_and_name_their_source():
    names = list_regulations()
    assert {"cn-2016-62", "gb1589-2016", "eu-96-53", "us-federal"} <= set(names)
    for name in names:
        reg = load_regulation(name)
        assert reg.name == name
        assert reg.title.strip() and reg.source.strip()
        assert reg.default_class in reg.classes
        for lims in reg.classes.values():
            assert all(v > 0 for v in lims.values())


def test_default_is_china_order_62_article_3():
    reg = load_regulation()
    assert reg.name == DEFAULT_REGULATION == "cn-2016-62"
    assert "62" in reg.source and "Article 3" in reg.source
    assert reg.limits() == {"length": 18.1, "width": 2.55, "height": 4.0}


def test_builtin_values_of_other_tables():
    gb = load_regulation("gb1589-2016")
    assert gb.limits("semi-trailer-combination")["length"] == 17.1
    assert gb.limits("rigid-truck") == {"length": 12.0, "width": 2.55, "height": 4.0}
    assert gb.limits("refrigerated-rigid-truck")["width"] == 2.6
    assert gb.limits("full-trailer-train")["length"] == 20.0
    eu = load_regulation("eu-96-53")
    assert eu.limits("articulated-vehicle") == {"length": 16.5, "width": 2.55, "height": None}
    assert eu.limits("road-train")["length"] == 18.75
    us = load_regulation("us-federal")
    assert us.limits() == {"length": None, "width": pytest.approx(102 * 0.0254), "height": None}


# --- verdict logic ------------------------------------------------------------------------

def test_verdict_within_over_and_undecided_per_dimension():
    reg = load_regulation("cn-2016-62")
    dims = {"length": 17.0, "width": 2.60, "height": 3.95}
    unc = {"length": 0.05, "width": 0.01, "height": 0.05}
    v = over_limit_verdict(dims, unc, reg)
    d = v["dimensions"]
    assert d["length"]["verdict"] == "within"      # 17.0 + 0.1 <= 18.1
    assert d["width"]["verdict"] == "over"         # 2.60 - 0.02 > 2.55
    assert d["height"]["verdict"] == "undecided"   # 4.0 in [3.85, 4.05]
    assert v["overall"] == "over"
    assert d["width"]["margin_m"] == pytest.approx(2.55 - 2.60)
    assert d["length"]["limit_m"] == 18.1
    assert v["regulation"]["name"] == "cn-2016-62" and v["regulation"]["source"] == reg.source
    assert v["vehicle_class"] == "any" and v["class_is_default"] is True
    assert v["k_sigma"] == 2.0 and v["scale"] is None
    # without the over-width the overall verdict is undecided
    v2 = over_limit_verdict({**dims, "width": 2.50}, unc, reg)
    assert v2["overall"] == "undecided"
    v3 = over_limit_verdict({**dims, "width": 2.50, "height": 3.80}, unc, reg)
    assert v3["overall"] == "within"


# values and uncertainties are dyadic fractions so that value ± k·u is exact in binary
@pytest.mark.parametrize(
    "value, u, k, expected",
    [
        (4.0, 0.0, 2.0, "within"),        # equal to the limit: not exceeding it
        (4.0 + 2**-20, 0.0, 2.0, "over"),
        (4.5, 0.25, 2.0, "undecided"),    # low end exactly at the limit: not over
        (4.5 + 2**-20, 0.25, 2.0, "over"),
        (3.5, 0.25, 2.0, "within"),       # high end exactly at the limit: within
        (3.5 + 2**-20, 0.25, 2.0, "undecided"),
        (4.125, 0.125, 0.0, "over"),      # k = 0 compares the bare value
        (4.125, 0.125, 1.0, "undecided"),
        (4.125, 0.0625, 1.0, "over"),
    ],
)
def test_verdict_boundaries(value, u, k, expected):
    reg = load_regulation("cn-2016-62")
    v = over_limit_verdict({"length": 10.0, "width": 2.0, "height": value}, {"length": 0.0, "width": 0.0, "height": u}, reg, k_sigma=k)
    assert v["dimensions"]["height"]["verdict"] == expected
    assert v["overall"] == expected


def test_unknown_or_missing_uncertainty_is_undecided_and_missing_value_not_measured():
    reg = load_regulation()
    v = over_limit_verdict({"length": 10.0, "width": 2.0, "height": 3.0}, {"length": 0.01, "width": 0.01}, reg)
    assert v["dimensions"]["height"]["verdict"] == "undecided"
    assert v["dimensions"]["height"]["uncertainty_m"] is None
    v = over_limit_verdict({"length": 10.0, "width": 2.0, "height": None}, U0, reg)
    assert v["dimensions"]["height"]["verdict"] == "not-measured"
    assert v["overall"] == "undecided"
    v = over_limit_verdict({"length": 10.0, "width": 3.0, "height": math.nan}, U0, reg)
    assert v["overall"] == "over"


def test_no_limit_dimensions_say_so():
    eu = load_regulation("eu-96-53")
    v = over_limit_verdict({"length": 11.0, "width": 2.5, "height": 4.6}, {"length": 0.02, "width": 0.01, "height": 0.02}, eu)
    assert v["dimensions"]["height"]["verdict"] == "no-limit"
    assert v["dimensions"]["height"]["limit_m"] is None and v["dimensions"]["height"]["margin_m"] is None
    assert v["overall"] == "within"
    us = load_regulation("us-federal")
    v = over_limit_verdict({"length": 22.0, "width": 2.60, "height": 4.2}, {"length": 0.02, "width": 0.002, "height": 0.02}, us)
    assert [v["dimensions"][d]["verdict"] for d in ("length", "width", "height")] == ["no-limit", "over", "no-limit"]
    assert v["overall"] == "over"


def test_vehicle_class_selects_limits_and_unknown_class_lists_valid_ones():
    gb = load_regulation("gb1589-2016")
    dims = {"length": 16.0, "width": 2.5, "height": 3.9}
    unc = {"length": 0.05, "width": 0.01, "height": 0.01}
    assert over_limit_verdict(dims, unc, gb)["dimensions"]["length"]["verdict"] == "over"  # rigid truck 12 m
    v = over_limit_verdict(dims, unc, gb, vehicle_class="semi-trailer-combination")
    assert v["overall"] == "within" and v["class_is_default"] is False
    with pytest.raises(ConfigError) as err:
        over_limit_verdict(dims, unc, gb, vehicle_class="spaceship")
    assert "spaceship" in str(err.value) and "semi-trailer-combination" in str(err.value) and "rigid-truck" in str(err.value)


def test_model_scale_truck_gets_no_verdict_unless_scaled():
    reg = load_regulation()
    dims = {"length": 1.00, "width": 0.15, "height": 0.26}   # a 1:16 model of an over-height truck
    unc = {"length": 0.005, "width": 0.002, "height": 0.002}
    v = over_limit_verdict(dims, unc, reg)
    assert v["overall"] == "not-applicable"
    assert "model" in v["reason"] and "scale" in v["reason"]
    assert all(e["verdict"] == "not-applicable" and e["margin_m"] is None for e in v["dimensions"].values())
    vs = over_limit_verdict(dims, unc, reg, scale=16.0)
    assert vs["scale"] == 16.0
    h = vs["dimensions"]["height"]
    assert h["value_m"] == pytest.approx(0.26 * 16) and h["uncertainty_m"] == pytest.approx(0.002 * 16)
    assert h["verdict"] == "over"                     # 4.16 - 0.064 > 4.0
    assert vs["dimensions"]["length"]["verdict"] == "within"
    assert vs["overall"] == "over"


def test_bad_scale_and_k_sigma_and_negative_uncertainty():
    reg = load_regulation()
    dims = {"length": 10.0, "width": 2.0, "height": 3.0}
    for bad in (0.0, -2.0, math.inf, math.nan):
        with pytest.raises(ConfigError, match="scale"):
            over_limit_verdict(dims, U0, reg, scale=bad)
    with pytest.raises(ConfigError, match="k_sigma"):
        over_limit_verdict(dims, U0, reg, k_sigma=-1)
    with pytest.raises(InputError, match="uncertainty"):
        over_limit_verdict(dims, {**U0, "width": -0.1}, reg)


def test_dims_with_m_suffix_keys_are_accepted():
    reg = load_regulation()
    v = over_limit_verdict({"length_m": 12.0, "width_m": 2.6, "height_m": 3.0}, U0, reg)
    assert v["dimensions"]["width"]["verdict"] == "over"


# --- user tables --------------------------------------------------------------------------

def _write(path, data):
    if path.suffix == ".json":
        path.write_text(json.dumps(data))
    elif path.suffix in (".yaml", ".yml"):
        path.write_text(yaml.safe_dump(data))
    else:
        lines = []
        for k, v in data.items():
            if k != "classes":
                lines.append(f"{k} = {json.dumps(v)}")
        for cls, entry in data["classes"].items():
            lines.append(f"[classes.{cls}]")
            lines += [f"{k} = {json.dumps(v)}" for k, v in entry.items()]
        path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("suffix", [".toml", ".yaml", ".json"])
def test_custom_table_round_trip(tmp_path, suffix):
    path = _write(tmp_path / f"mine{suffix}", _table())
    reg = load_regulation(str(path))
    assert reg.name == "test-reg" and reg.source.endswith(".py")
    assert reg.limits() == {"length": 10.0, "width": 2.5, "height": 3.8}
    assert reg.limits("low") == {"length": None, "width": None, "height": 3.0}
    assert reg.class_descriptions["truck"] == "test truck"
    v = over_limit_verdict({"length": 9.0, "width": 2.4, "height": 3.5}, {"length": 0.01, "width": 0.01, "height": 0.01}, reg, vehicle_class="low")
    assert v["overall"] == "over" and v["dimensions"]["length"]["verdict"] == "no-limit"


@pytest.mark.parametrize(
    "change, key",
    [
        ({"colour": "red"}, "colour"),
        ({"classes": {"truck": {"length_m": 10.0, "lenght_m": 9.0}}}, "lenght_m"),
        ({"classes": {"truck": {"length_m": 0.0}}}, "classes.truck.length_m"),
        ({"classes": {"truck": {"width_m": -2.5}}}, "classes.truck.width_m"),
        ({"classes": {"truck": {"height_m": "4 m"}}}, "classes.truck.height_m"),
        ({"classes": {"truck": {"height_m": True}}}, "classes.truck.height_m"),
        ({"default_class": "bus"}, "default_class"),
        ({"classes": {}}, "classes"),
        ({"source": ""}, "source"),
    ],
)
def test_custom_table_strict_validation(tmp_path, change, key):
    path = _write(tmp_path / "bad.json", _table(**change))
    with pytest.raises(ConfigError) as err:
        load_regulation(str(path))
    msg = str(err.value)
    assert str(path) in msg and key in msg and "\n" not in msg


def test_custom_table_missing_key_and_bad_files(tmp_path):
    data = _table()
    del data["title"]
    path = _write(tmp_path / "notitle.yaml", data)
    with pytest.raises(ConfigError, match="notitle.yaml.*'title'"):
        load_regulation(str(path))
    broken = tmp_path / "broken.toml"
    broken.write_text("name = \n")
    with pytest.raises(ConfigError, match="broken.toml: cannot parse"):
        load_regulation(str(broken))
    with pytest.raises(ConfigError, match="not found"):
        load_regulation(str(tmp_path / "absent.toml"))
    with pytest.raises(ConfigError, match="unknown regulation 'mars-2050'.*cn-2016-62"):
        load_regulation("mars-2050")
    lst = tmp_path / "list.json"
    lst.write_text("[1, 2]")
    with pytest.raises(ConfigError, match="list.json"):
        load_regulation(str(lst))


def test_regulations_help_lists_every_table_and_class():
    text = regulations_help()
    for name in list_regulations():
        reg = load_regulation(name)
        assert f"{name}: {reg.title}" in text
        for cls in reg.classes:
            assert cls in text
    assert "any (default): length 18.1 m, width 2.55 m, height 4 m" in text
    assert "commercial-motor-vehicle (default): length no limit, width 2.5908 m, height no limit" in text
