"""Segmentation stage (not built yet, issue 3): U-Net, training CLI, inference backends, segmentation_node."""
