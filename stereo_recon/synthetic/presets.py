"""Named synthetic scenes: the paper's model trucks (Table 2), full-size trucks, two vehicles, a calibration board.

Model-scale presets follow the paper's experiment (model trucks about 1-2.4 m long on the ground,
the drone about 1 m up); full-scale presets a 12 m truck seen from ~10 m.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from stereo_recon.core.errors import ConfigError
from stereo_recon.synthetic.flight import OrbitConfig
from stereo_recon.synthetic.scene import TruckSpec

# Table 2 of the paper ("Experimental results"): standard size (length, width, height, m) of the
# twenty model trucks measured with a plumb and a laser rangefinder, and the paper's predicted size.
TABLE2_STANDARD_M: tuple[tuple[float, float, float], ...] = (
    (1.157, 0.180, 0.307), (1.151, 0.179, 0.316), (1.084, 0.183, 0.308), (1.071, 0.177, 0.324),
    (1.071, 0.177, 0.307), (1.065, 0.182, 0.323), (2.184, 0.384, 0.375), (2.184, 0.384, 0.385),
    (2.308, 0.324, 0.335), (2.106, 0.384, 0.380), (2.106, 0.384, 0.370), (2.102, 0.384, 0.335),
    (2.102, 0.384, 0.355), (2.384, 0.352, 0.420), (2.384, 0.352, 0.420), (2.408, 0.352, 0.420),
    (2.307, 0.361, 0.415), (2.307, 0.370, 0.415), (2.172, 0.370, 0.415), (2.172, 0.370, 0.415),
)
TABLE2_PREDICTED_M: tuple[tuple[float, float, float], ...] = (
    (1.184, 0.184, 0.31), (1.184, 0.184, 0.32), (1.106, 0.184, 0.315), (1.106, 0.184, 0.325),
    (1.102, 0.184, 0.315), (1.102, 0.184, 0.325), (2.161, 0.372, 0.377), (2.112, 0.372, 0.394),
    (2.242, 0.334, 0.341), (2.025, 0.371, 0.375), (2.056, 0.38, 0.373), (2.098, 0.374, 0.331),
    (2.061, 0.379, 0.359), (2.357, 0.361, 0.411), (2.351, 0.361, 0.427), (2.351, 0.345, 0.431),
    (2.269, 0.37, 0.41), (2.262, 0.378, 0.406), (2.099, 0.362, 0.419), (2.097, 0.367, 0.421),
)
# Body style per Table 2 subject (the paper shows photos only; chosen to vary the shapes).
_TABLE2_BODY = ("box", "box", "flatbed", "box", "box", "flatbed", "box", "box", "flatbed", "box",
                "box", "flatbed", "box", "semi", "semi", "semi", "box", "flatbed", "box", "semi")
_COLOURS = ((0.75, 0.12, 0.10), (0.10, 0.35, 0.70), (0.90, 0.70, 0.10), (0.15, 0.50, 0.25), (0.85, 0.85, 0.85))

# China's GB 1589-2016 (MIIT/MPS announcement 2016 No. 62) outer limits used for the expectation.
CN_2016_62_LIMITS_M = {"height_m": 4.0, "width_m": 2.55, "length_m": 18.1}


@dataclass(frozen=True)
class Preset:
    """A named synthetic scene and its default flight.

    kind: "truck" or "calibration-board"; scale: "model" or "full" (model trucks are not vehicles
    under the regulation: their over-limit expectation is "not-applicable").
    texel_m: noise texel (~ half a HD720 pixel footprint at the working distance).
    """

    name: str
    kind: str = "truck"
    scale: str = "model"
    truck: TruckSpec | None = None
    second_truck: TruckSpec | None = None
    second_gap_m: float | None = None
    orbit: OrbitConfig = OrbitConfig()
    frames: int = 60
    n_distractors: int = 6
    texel_m: float | None = None
    truck_yaw_deg: float = 20.0
    extra: dict = field(default_factory=dict)


def _model_orbit(length_m: float, height_m: float) -> OrbitConfig:
    r = max(0.81 * length_m, 1.0)
    return OrbitConfig(radius_m=r, altitude_m=max(0.48 * length_m, 0.7), look_height_m=0.4 * height_m,
                       jitter_deg=0.6, position_jitter_m=0.006 * length_m, fps=15.0)


def _texel(orbit: OrbitConfig) -> float:
    dist = (orbit.radius_m ** 2 + (orbit.altitude_m - orbit.look_height_m) ** 2) ** 0.5
    return 0.5 * dist / 528.0


def _full_orbit(height_m: float) -> OrbitConfig:
    return OrbitConfig(radius_m=9.5, altitude_m=6.5, look_height_m=0.4 * height_m, jitter_deg=0.5, position_jitter_m=0.08, fps=15.0)


def preset_names() -> list[str]:
    """All preset names (``table2:N`` for N = 1..20)."""
    return ["model-truck", "full-truck", "over-height", "two-vehicles", "calibration-board"] + [f"table2:{i}" for i in range(1, 21)]


def get_preset(name: str) -> Preset:
    """The preset called ``name``; unknown names raise a one-line ConfigError listing the choices."""
    key = name.strip().lower()
    if key == "model-truck":
        spec = TruckSpec(2.1, 0.38, 0.38, "box", (0.75, 0.12, 0.10))
        o = _model_orbit(spec.length_m, spec.height_m)
        return Preset(name=key, truck=spec, orbit=o, texel_m=_texel(o))
    if key in ("full-truck", "over-height"):
        spec = TruckSpec(12.0, 2.55, 4.0 if key == "full-truck" else 4.3, "box", (0.10, 0.35, 0.70))
        o = _full_orbit(spec.height_m)
        return Preset(name=key, scale="full", truck=spec, orbit=o, texel_m=_texel(o))
    if key == "two-vehicles":
        spec = TruckSpec(2.1, 0.38, 0.38, "box", (0.75, 0.12, 0.10))
        second = TruckSpec(1.9, 0.36, 0.34, "flatbed", (0.15, 0.50, 0.25), stripe=False)
        o = OrbitConfig(radius_m=2.0, altitude_m=1.2, look_height_m=0.15, jitter_deg=0.6, position_jitter_m=0.012, fps=15.0)
        return Preset(name=key, truck=spec, second_truck=second, second_gap_m=0.25, orbit=o, texel_m=_texel(o), n_distractors=4)
    if key == "calibration-board":
        return Preset(name=key, kind="calibration-board", frames=30, n_distractors=0,
                      orbit=OrbitConfig(radius_m=0.0, altitude_m=1.2, fps=15.0), texel_m=0.0015,
                      extra={"inner_corners": (9, 6), "square_m": 0.06, "margin_m": 0.05})
    if key.startswith("table2:"):
        try:
            i = int(key.split(":", 1)[1])
        except ValueError:
            i = 0
        if not 1 <= i <= 20:
            raise ConfigError(f"--preset {name}: table2 subjects are numbered 1..20")
        L, W, H = TABLE2_STANDARD_M[i - 1]
        spec = TruckSpec(L, W, H, _TABLE2_BODY[i - 1], _COLOURS[i % len(_COLOURS)], stripe=_TABLE2_BODY[i - 1] != "flatbed")
        o = _model_orbit(L, H)
        return Preset(name=key, truck=spec, orbit=o, texel_m=_texel(o), truck_yaw_deg=10.0 + 7.0 * i,
                      extra={"table2_subject": i, "table2_standard_m": TABLE2_STANDARD_M[i - 1], "table2_paper_predicted_m": TABLE2_PREDICTED_M[i - 1]})
    raise ConfigError(f"--preset: unknown preset {name!r}; choose one of model-truck, full-truck, over-height, two-vehicles, calibration-board, table2:1..table2:20")


def over_limit_expectation(preset: Preset) -> dict:
    """What a correct measurement should conclude under China's 2016 No. 62 limits (GB 1589-2016)."""
    out = {"regulation": "cn-2016-62", "limits_m": dict(CN_2016_62_LIMITS_M)}
    if preset.truck is None:
        out.update(verdict="not-applicable", reason="no vehicle in the scene")
        return out
    if preset.scale == "model":
        out.update(verdict="not-applicable", reason="model-scale truck (the paper's experiment); limits apply to real vehicles")
        return out
    t = preset.truck
    dims = {"length_m": t.length_m, "width_m": t.width_m, "height_m": t.height_m}
    over = {k: dims[k] > CN_2016_62_LIMITS_M[k] for k in dims}
    out.update(verdict="over-limit" if any(over.values()) else "within-limits", over=over,
               margin_m={k: round(dims[k] - CN_2016_62_LIMITS_M[k], 6) for k in dims})
    return out
