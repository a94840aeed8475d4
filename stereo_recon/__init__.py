"""stereo-recon: truck dimensions from drone stereo video.

Pipeline (one module per stage, data flows forward):
video -> frames -> rectified pairs -> depth -> poses -> volume -> cloud -> measurement -> report.

Conventions are written once, in :mod:`stereo_recon.core.conventions`.
"""

__version__ = "0.1.0"
