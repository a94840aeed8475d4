"""The one owner of an output folder's names: every writer, reader, ``--resume`` and the report use these.

A run's folder (``stereo-recon run``; ``reconstruct`` and ``measure`` write their part of it)::

    cloud.ply          fused point cloud, world frame of the first left camera, metres (reconstruct)
    poses.txt          TUM trajectory, world-from-left-camera (reconstruct)
    run.json           reconstruction manifest: inputs, parameters, timings, 'up' (reconstruct)
    mesh.ply           marching-cubes surface, with --mesh (reconstruct)
    work/              keyframe images and depth maps, with --keep-work (reconstruct)
    measurement.json   the measurement and verdict (measure)
    measure_run.json   the measure stage's manifest: times, dates (measure)
    *.png, keyframe.jpg  the report's plots and the frame with the measured box (measure)
    report.html        self-contained report (measure)
    job.json           the job's own manifest: stages, fingerprint for --resume, verdict (run)
    log.txt            debug log of every command run into the folder (the CLI)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

CLOUD = "cloud.ply"
POSES = "poses.txt"
RUN_JSON = "run.json"
MESH = "mesh.ply"
WORK = "work"
MEASUREMENT = "measurement.json"
MEASURE_RUN = "measure_run.json"
REPORT = "report.html"
JOB = "job.json"
LOG = "log.txt"
KEYFRAME = "keyframe.jpg"
SUMMARY_CSV = "summary.csv"   # a batch folder's one row per recording
# The measure stage's plots (paper Figs. 5-6, top and side views), named by their key in measurement.json.
PLOTS = ("width_density.png", "length_density.png", "top_view.png", "side_view.png")

# Files of a run's folder that belong to the run: a new run replaces them all (an earlier run's
# mesh.ply or plots never sit beside a new cloud); anything else in the folder is kept.
RUN_OUTPUTS = frozenset({CLOUD, POSES, RUN_JSON, MESH, WORK, MEASUREMENT, REPORT, JOB, MEASURE_RUN, *PLOTS, KEYFRAME})
# The reconstruction's files, reused by --resume when every input that made them is unchanged.
RECONSTRUCTION_FILES = (CLOUD, POSES, RUN_JSON, MESH)
# Files that mark a folder as one of this program's outputs (an existing folder without any of them
# and with other content is not replaced: it is probably the user's own).
OUTPUT_MARKERS = (RUN_JSON, JOB, MEASUREMENT, CLOUD, REPORT, POSES)


@dataclass(frozen=True)
class RunPaths:
    """Every path of one run's output folder (the tree above; documented in the README)."""

    root: Path

    @property
    def cloud(self) -> Path:  # fused point cloud, world frame of the first left camera
        return self.root / CLOUD

    @property
    def poses(self) -> Path:  # TUM, world-from-left-camera
        return self.root / POSES

    @property
    def run_json(self) -> Path:  # reconstruction manifest (inputs, parameters, timings, 'up')
        return self.root / RUN_JSON

    @property
    def mesh(self) -> Path:  # marching-cubes surface (--mesh)
        return self.root / MESH

    @property
    def work(self) -> Path:  # keyframe images and depth maps (--keep-work)
        return self.root / WORK

    @property
    def measurement(self) -> Path:  # measure stage result
        return self.root / MEASUREMENT

    @property
    def measure_run(self) -> Path:  # measure stage manifest (times and dates)
        return self.root / MEASURE_RUN

    @property
    def keyframe(self) -> Path:  # a video frame with the measured box drawn on it
        return self.root / KEYFRAME

    @property
    def report(self) -> Path:  # self-contained HTML report
        return self.root / REPORT

    @property
    def summary(self) -> Path:  # this job's own manifest: stages, times, verdict
        return self.root / JOB

    @property
    def log(self) -> Path:  # the CLI's debug log
        return self.root / LOG
