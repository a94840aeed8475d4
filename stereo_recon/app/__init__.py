"""The application layer: the ``stereo-recon`` command, the end-to-end job, batch, bench and the report's keyframe.

Sits on top of everything (reconstruction stages, ``calib``, ``measure``, ``synthetic``, ``core``); nothing imports it.
"""
