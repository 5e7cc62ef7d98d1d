"""Reconstruction stage (not built yet, issue 5): stereo pairing, triangulation, shape optimiser, grasp pose."""
