"""How far a Gaussian KDE's ripples of pure sampling noise stand out, in standard errors of the density (not a test).

Why: the width rule takes its walls from the projection density's peaks, and a ripple on a wall's outer flank
must not pass for one (``DimensionConfig.peak_min_prominence_sigmas``). This draws points uniform on [0, 1] m
(no surface, only noise) at several counts and bandwidths, smooths them as the width rule does
(``measure.kde.smooth_counts``), and prints the prominence (``scipy.signal.peak_prominences``) of every ripple
inside [0.05, 0.95] m over the kernel's standard error at it (``measure.kde.kde_standard_error``): its quantiles, and
those of the highest ripple of each stretch. The stretch's highest ripple is left out of both (its prominence
runs down to the empty ends, its full height).

Run:  .venv/bin/python benchmarks/bench_peak_noise.py [--stretches 200] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.signal import peak_prominences

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from measure.kde import kde_standard_error, linear_binning, local_maxima, smooth_counts  # noqa: E402


def ripple_prominences(n: int, h: float, rng) -> np.ndarray:
    """Prominences (in standard errors) of the ripples of n uniform points on [0, 1] m smoothed at bandwidth h (m)."""
    x = rng.uniform(0.0, 1.0, n)
    step, lo = h / 8, -0.2
    nb = int(1.4 / step)
    dens = smooth_counts(linear_binning(x, lo, step, nb), step, h)
    grid = lo + step * np.arange(nb)
    pk = local_maxima(dens)
    pk = pk[(grid[pk] > 0.05) & (grid[pk] < 0.95)]
    se = kde_standard_error(dens[pk], n, h)
    r = peak_prominences(dens, pk)[0] / se
    return np.delete(r, np.argmax(dens[pk]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--stretches", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    every, highest, sizes = [], [], []
    for _ in range(args.stretches):
        r = ripple_prominences(int(rng.choice([5_000, 20_000, 80_000])), float(rng.choice([0.002, 0.005, 0.01])), rng)
        every.append(r)
        highest.append(r.max())
        sizes.append(len(r))
    every = np.concatenate(every)
    q = (50, 90, 99, 99.9)
    print(f"{len(every)} ripples in {args.stretches} stretches (median {np.median(sizes):.0f} per stretch)")
    print("ripple prominence / standard error, percentiles " + ", ".join(f"{p}: {v:.2f}" for p, v in zip(q, np.percentile(every, q))))
    print("a stretch's highest ripple, percentiles " + ", ".join(f"{p}: {v:.2f}" for p, v in zip(q[:3], np.percentile(highest, q[:3]))))
    for k in (2.0, 3.0, 4.0, 5.0):
        print(f"  k = {k}: {100 * np.mean(every >= k):.2f} % of ripples, {100 * np.mean(np.array(highest) >= k):.1f} % of stretches pass")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
