"""Reconstruction stage (not built yet, issue 5).

Stereo pairing, triangulation, shape optimiser, grasp pose.
"""
