"""The bottom layer: errors, conventions, run manifests, the one atomic writer and folder transaction,
the output folder's names, progress, argument checks, the one point-cloud writer and side-by-side reader.

Imports nothing of the project outside ``stereo_recon.core`` (checked by tests/test_architecture.py).
"""
