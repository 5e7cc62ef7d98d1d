# SPDX-License-Identifier: Apache-2.0
"""Robot backends behind one small interface (:class:`grasp_executor.backends.base.Backend`).

``dry_run`` (moves nothing), ``dvrk`` (CRTK topics through a transport seam) and
``ur`` (ur_rtde, imported lazily). None of them checks safety: every command
reaches a backend through :class:`grasp_executor.safety.GuardedBackend`.
"""
