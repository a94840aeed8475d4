"""Coordinate conventions used by every stage of stereo-recon (written once, here).

Camera frame
    OpenCV: x to the right, y down, z forward (optical axis), metres.

Poses
    A pose ``T_wc`` is **world-from-camera**: ``X_world = R_wc @ X_cam + t_wc``; the camera
    centre in the world is ``t_wc``. ``poses.txt`` is TUM format, one line per frame:
    ``timestamp tx ty tz qx qy qz qw`` with timestamp = frame index / fps, describing the
    *left* camera (world-from-left-camera).

Stereo rig extrinsics
    OpenCV ``stereoCalibrate`` convention: ``X_right = R @ X_left + T`` (metres). A right eye
    to the right of the left eye therefore has ``T ~ [-B, 0, 0]`` with baseline ``B > 0``.

Images
    Side-by-side frames hold the left eye in the left half. Image sizes are ``(width, height)``
    in pixels, as OpenCV takes them.

Ground-aligned frame (measurement)
    Origin on the fitted ground plane, ``z`` up along the ground normal, ``x`` along the truck
    length (rear -> front), ``y`` along the width (right-handed).
"""
