"""The overhead camera: camera model, marker detection and refinement, calibration, synthetic
camera. Imports core/ base only.
"""
