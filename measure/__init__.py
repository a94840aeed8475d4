"""Truck outer-contour measurement on point clouds (paper Sections 3.1–3.2).

Stages, one module each: :mod:`measure.resolution` (point spacing), :mod:`measure.ground`
(Algorithm 1, ground removal), :mod:`measure.fof` (Algorithm 2), :mod:`measure.truck` (cluster
filters and choice), :mod:`measure.dimensions` (Eqs. 5–9), :mod:`measure.limits` (over-limit
verdicts), :mod:`measure.plots` / :mod:`measure.report_html` (report); :mod:`measure.pipeline`
chains them and :mod:`stereo_recon.app.measure_cli` is the ``stereo-recon measure`` command.
"""
