"""Grasp executor (not built yet, issue 6): safety checks, dry_run / dVRK / UR backends, executor_node."""
