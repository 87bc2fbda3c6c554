"""Calibrated geometry: camera models, the relative pose from F, and the stereo calibration
check."""
