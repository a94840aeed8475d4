"""Stereo rig calibration: the rig model and rectification, rig files (ZED .conf, OpenCV YAML/XML,
the project's rig YAML), calibration from board views, and calibration checks.

Other stages use :class:`StereoRig`, :func:`rectify_pair`, :func:`load_rig` and :func:`parse_calib_arg`.
"""

from calib.io import load_rig, parse_calib_arg, save_rig, write_zed_conf
from calib.rig import Rectification, StereoRig, rectify_pair

__all__ = ["StereoRig", "Rectification", "rectify_pair", "load_rig", "save_rig", "write_zed_conf", "parse_calib_arg"]
