"""Help texts of the ``stereo-recon`` command: an example per subcommand, defaults on every option, exit codes.

Kept apart from the command modules so each one's ``register`` stays as it is; :func:`finish_help`
runs after all of them have added their parsers.
"""

from __future__ import annotations

import argparse
import re
import textwrap

# What the process's exit status means, for every subcommand (also in the README).
EXIT_CODES = """exit status:
  0    done (calib-check: the calibration fits the video)
  1    the command ran and found a problem to act on: calib-check's calibration does not fit the
       video (mismatch, already rectified, swapped eyes, too few matches); batch/bench: a recording failed
  2    the command could not do its job: a bad option, an unreadable or unsuitable input, or a stage
       that failed on it (one line on stderr names the file and the problem; no output folder is left)
  130  interrupted (Ctrl-C)"""

# Examples, one per subcommand, shown under its --help.
EXAMPLES = {
    "run": """examples:
  stereo-recon run                                  # the bundled sample, into out/run
  stereo-recon calib-check flight.avi --calib SN28000001.conf
  stereo-recon run flight.avi --calib SN28000001.conf --out out/truck7 \\
      --regulation gb1589-2016 --site "G4 toll gate 12" --operator "Li Wei" --case-id 2026-0117""",
    "batch": """examples:
  stereo-recon batch flights/*.avi --calib SN28000001.conf --out season --workers 2
  stereo-recon batch flights/*.avi --calib SN28000001.conf --out season --executor ray --address auto
  RAY_ADDRESS=10.0.0.5:6379 stereo-recon batch flights/*.avi --calib SN28000001.conf --out season --executor ray
  stereo-recon batch flights/day2/*.avi --calib SN28000001.conf --out season --resume   # merges into season/summary.csv""",
    "bench": """example:
  stereo-recon bench --trucks 1-3 --no-full-scale --out out/bench-quick   # three model trucks, a few minutes
  stereo-recon bench --out out/bench                                      # the paper's Table 2 + full scale""",
    "reconstruct": """example:
  stereo-recon reconstruct flight.avi --calib SN28000001.conf --out out/recon --frames 100:400 --step 2
  stereo-recon reconstruct flight.avi --calib SN28000001.conf --out out/recon --export-colmap out/recon/colmap""",
    "measure": """example:
  stereo-recon measure out/run/cloud.ply --out out/measure --up=0,-1,0 --regulation cn-2016-62
  stereo-recon measure scan.ply --out out/scan --scale 10 --case-id 2026-0117   # a 1:10 model""",
    "calibrate": """example:
  stereo-recon calibrate board.avi --board chessboard:9x6:0.025 --out rig.yaml
  stereo-recon calibrate pairs/ --board charuco:11x8:0.03:0.022:DICT_5X5_100 --out rig.yaml --zed-conf calib/""",
    "calib-check": """example:
  stereo-recon calib-check flight.avi --calib SN28000001.conf && echo "calibration fits"
  stereo-recon calib-check flight.avi --calib rig.yaml --out check.json; echo "exit $?"   # 1 = does not fit""",
    "synth": """example:
  stereo-recon synth --preset model-truck --out out/synth && stereo-recon run out/synth/video.avi \\
      --calib out/synth/SN28000001.conf --out out/synth-run""",
}

MAIN_EPILOG = """getting started:
  stereo-recon run                          # the bundled sample: video -> cloud -> measurement -> report.html
  stereo-recon COMMAND --help               # each command's options, defaults and an example

""" + EXIT_CODES


class HelpFormatter(argparse.HelpFormatter):
    """Wraps prose, keeps indented lines (examples) as written, and ends every option's help with its default."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        out = []
        for para in text.split("\n\n"):
            lines = para.splitlines()
            if any(ln.startswith("  ") for ln in lines[1:]) or para.startswith("  "):
                out.append("\n".join(indent + ln for ln in lines))  # an example block: verbatim
            else:
                out.append(textwrap.fill(" ".join(para.split()), width, initial_indent=indent, subsequent_indent=indent))
        return "\n\n".join(out)

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if not action.option_strings or action.default is argparse.SUPPRESS or re.search(r"\bdefault", text, re.I):
            return text
        if isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
            return text
        if action.required:
            return f"{text} (required)"
        if isinstance(action, argparse._StoreTrueAction) or action.default is False:
            return f"{text} (default: off)"
        if action.default is None:
            return f"{text} (default: none)"
        return f"{text} (default: %(default)s)"


def finish_help(parser: argparse.ArgumentParser, subparsers: argparse._SubParsersAction) -> None:
    """Give the main parser and every subcommand the formatter, the examples and the exit codes."""
    parser.formatter_class = HelpFormatter
    parser.epilog = MAIN_EPILOG
    for name, sp in subparsers.choices.items():
        sp.formatter_class = HelpFormatter
        example = EXAMPLES.get(name)
        sp.epilog = (example + "\n\n" if example else "") + "exit status: 0 done, 1 a finding to act on, 2 could not " \
                                                            "do its job (see stereo-recon --help)"
