"""Choosing a parameter from training trucks of known size (paper Eq. 4).

The paper picks the ground thickness d_h* = argmin over d_h of the mean squared error between
the measured and the tape-measured (length, width, height) of six training trucks. This does the
same for any numeric field of :class:`measure.pipeline.MeasureConfig`.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence

import numpy as np

from measure.pipeline import MeasureConfig, measure_points
from stereo_recon.core.errors import ConfigError, StereoReconError

log = logging.getLogger(__name__)


def tune_by_mse(clouds: Sequence[np.ndarray], truths: Sequence[dict], field: str = "ground_thickness_res",
                values: Sequence[float] = (3.0, 3.25, 3.5, 3.75, 4.0), config: MeasureConfig = MeasureConfig()) -> dict:
    """Eq. 4: the value of ``field`` minimising the mean over clouds of ||(l, w, h) − (l0, w0, h0)||².

    clouds: (N_i, 3) point arrays, metres. truths: dicts with ``length_m``, ``width_m``, ``height_m``.
    A cloud that fails to measure at some value counts as an infinite error there.
    Returns {"field", "best", "table": [{"value", "mse_m2", "errors_m": [[dl, dw, dh], ...]}]}.
    """
    if field not in {f.name for f in dataclasses.fields(MeasureConfig)}:
        raise ConfigError(f"tune_by_mse: unknown MeasureConfig field {field!r}")
    if len(clouds) != len(truths) or not clouds:
        raise ConfigError("tune_by_mse: need as many truths as clouds (at least one)")
    table = []
    for v in values:
        cfg = dataclasses.replace(config, **{field: v})
        errs = []
        for pts, t in zip(clouds, truths):
            try:
                m = measure_points(pts, cfg)
                errs.append([m.length_m - t["length_m"], m.width_m - t["width_m"], m.height_m - t["height_m"]])
            except StereoReconError as err:
                log.info("tune_by_mse: %s = %s failed: %s", field, v, err)
                errs.append([np.inf] * 3)
        e = np.asarray(errs, dtype=np.float64)
        table.append({"value": float(v), "mse_m2": float(np.mean(np.sum(e**2, axis=1))), "errors_m": e.tolist()})
    best = min(table, key=lambda r: r["mse_m2"])
    return {"field": field, "best": best["value"], "table": table}
