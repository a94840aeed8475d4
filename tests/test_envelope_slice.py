"""CI slice of the operating-envelope benchmark: short random draws through the real pipeline, held to the issue's bounds.

Draws 0-2 of seed SLICE_SEED, capped at SLICE_FRAMES frames: the first tuning seed from 10 on
whose first three draws hold both scales (two model, one full: full-scale runs cost ~3x more)
and three body kinds; chosen for coverage, not because they pass. Bounds, from issue 12's
targets for the 40-draw benchmark: no failure; no dimension worse than 3.0 %; the truth inside the
reported +-2 sigma for at least 7 of the 9 dimensions (90 % coverage leaves a 9-dimension slice
at <= 6 covered with 5 % probability); every full-scale verdict sound (``bench.verdict_matches`` with
``undecided="interval-covers-truth"``: ``over`` and ``within`` on the truth's side, ``undecided`` with the truth inside
the measurement's own +-2 sigma). Not the issue's letter (``undecided`` only with the truth within 2 sigma of the
limit), which the benchmark reports beside it: draw 0's truth lies 2.01 sigma under the width limit, where a calibrated
sigma makes ``undecided`` as likely as not (any error towards the limit), so that check passed on AMD EPYC machines and
failed on Intel Xeon ones on the same code (2026-11-30) - it judged the sign of a 1.8 % error, not the verdict.
"""

import shutil

import pytest

from stereo_recon.app.bench import DIMS, bench_random_one, envelope_row
from stereo_recon.synthetic.envelope import draw_spec

SLICE_SEED = 21
SLICE_FRAMES = 48
MAX_ABS_ERROR_PCT = 3.0

# Where the pipeline does not yet meet the bounds (issue 12, item 3): draw index -> the failure mode seen.
# Figures of main on 2026-11-24 (fourth round); the strict xfail checks that they still fail. Remove an entry when
# the pipeline meets the bounds. Draw 2 (a 1.19 m semi-trailer from 2.4 m at 20 deg: W +14.0 %, H -5.6 % on the rig's
# depth) met them once far scenes started at 14.2 rig baselines (it is 16.4 away: motion stereo, L -0.8, W -2.6,
# H -1.9 %), but only on a renderer whose panel stains changed between frames; with the texture fixed to the world
# (sixth round) its walls come out inside like the external renders' (W -3.7 %). Since the eighth round's scale fix
# (24453f1, 2026-11-26) it meets them again, narrowly: L -1.0, W -2.9, H -1.9 %. Draw 1 (a model tanker from 3.7 m,
# plain paint, noise 5.3 DN, motion stereo: W -5.2 % from the walls' peaks) meets them since its width is read at the
# tank's widest height (ae49134, 2026-11-26): L -0.9, W -1.1 (the peaks: -3.1), H -2.7 %. Draw 0 (a full-scale 7.6 m
# box seen from 20.5 m at 46 deg, plain paint, 1.9 % contrast, a shorter vehicle 1.8 W away: L +3.6, W +2.2, H +0.1 % on
# 2026-11-24) meets them since its walls are read from their plateau (34b8a08, 2026-11-26): L +2.2, W +2.0 (the
# peaks: +6.4), H -0.1 %, `undecided` (right: its truth lies within 2 sigma of a limit). On an AMD EPYC machine
# (2026-11-28) its cloud differs and read L +3.47 %: a skirt of ground points hovering past its black cab's face
# made all points' front peak; since an end peak beyond the points above the skirt is no end (length_min_height,
# 2026-11-29): L +1.04, W +2.70, H +0.49 % there.
KNOWN_FAILURES: dict[int, str] = {}
# Coverage was 3 of 9 on e875b61 (the bootstrap saw only the cloud's scatter); met since the depth term's k_px was
# recalibrated on 83 tuning runs (2026-11-24, seed 21 not among them), which this strict check found.
COVERAGE_KNOWN_FAILURE: str | None = None

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def slice_rows(tmp_path_factory):
    root = tmp_path_factory.mktemp("envelope-slice")
    rows = {}
    for i in range(3):
        spec = draw_spec(SLICE_SEED, i, max_frames=SLICE_FRAMES)
        try:
            result = {"name": spec.name, "ok": True, **bench_random_one(SLICE_SEED, i, str(root / "draws"), str(root / "runs" / str(i)),
                                                                         SLICE_FRAMES, None, "HD720")}
        except Exception as err:  # a failure is a result here: the row records its reason
            result = {"name": spec.name, "ok": False, "error": f"{type(err).__name__}: {err}"}
        rows[i] = envelope_row(result, spec)
        # Each draw's video and run (~100-400 MB) go once its row holds what the tests read: the disk stays small.
        for done in (root / "draws", root / "runs" / str(i)):
            shutil.rmtree(done, ignore_errors=True)
    return rows


def _draw_param(i):
    marks = [pytest.mark.xfail(strict=True, reason=KNOWN_FAILURES[i])] if i in KNOWN_FAILURES else []
    return pytest.param(i, marks=marks, id=f"draw{i}")


@pytest.mark.parametrize("index", [_draw_param(i) for i in range(3)])
def test_slice_draw_is_measured_within_bounds(slice_rows, index):
    row = slice_rows[index]
    assert row["ok"], f"{row['name']} ({row['spec']['scale']} {row['spec']['kind']}) failed: {row['failure_reason']}"
    worst = max(abs(row["error_pct"][d]) for d in DIMS)
    assert worst <= MAX_ABS_ERROR_PCT, f"{row['name']}: errors {row['error_pct']}"
    if row["spec"]["scale"] == "full":
        assert row["verdict_sound"], (f"{row['name']}: verdict {row['verdict']}, truth expects {row['expected_verdict']}; "
                                      f"measured {row['measured_m']} +- {row['sigma_m']}, truth {row['truth_m']}")


@pytest.mark.xfail(COVERAGE_KNOWN_FAILURE is not None, strict=True, reason=COVERAGE_KNOWN_FAILURE or "")
def test_slice_uncertainty_covers_the_truth(slice_rows):
    covered = sum(bool(r["within_2sigma"] and r["within_2sigma"][d]) for r in slice_rows.values() for d in DIMS)
    assert covered >= 7, {r["name"]: (r["error_pct"], r["sigma_m"]) for r in slice_rows.values()}


def test_slice_spans_the_envelope():
    specs = [draw_spec(SLICE_SEED, i, max_frames=SLICE_FRAMES) for i in range(3)]
    assert {s.truck.scale for s in specs} == {"model", "full"}
    assert len({s.truck.kind for s in specs}) == 3 and sum(s.truck.scale == "model" for s in specs) == 2
    assert all(s.flight.frames == SLICE_FRAMES for s in specs)
