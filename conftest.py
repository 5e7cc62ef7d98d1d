# SPDX-License-Identifier: Apache-2.0
"""Repository-wide pytest set-up: hypothesis under CI, and the tests' ROS 2 (DDS) domains.

Property tests are derandomised under CI, so a submission's CI run tries exactly the examples
that `CI=true bash ros2_ws/test.sh` tried locally.

Every test that starts rclpy takes its DDS domain from the :func:`ros_domain_id` fixture, the
one allocation of the suite. A test run holds one slot of :data:`DOMAINS_PER_RUN` consecutive
domains (slot k: domains 1 + k * DOMAINS_PER_RUN ...), locked for the run's lifetime, so test runs
side by side on one host never share a domain; within the run every test module gets its own
domain, so nodes a test leaves behind cannot talk to the next module's. All domains lie in
1..100, inside the 0..101 range that ROS 2 documents as safe on every platform (0, the
default domain of a live system, is never used).
"""

from __future__ import annotations

import fcntl
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO

import pytest
from hypothesis import settings

settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")

DOMAINS_PER_RUN = 20
"""Domains one test run may use: more than the modules that start rclpy."""
RUN_SLOTS = 100 // DOMAINS_PER_RUN
LOCK_DIR = Path(tempfile.gettempdir()) / "suture-test-ros-domains"


def _lock_free_slot() -> tuple[int, IO[bytes]]:
    """The first slot no other test run on this host holds, with its (held) lock file."""
    LOCK_DIR.mkdir(exist_ok=True)
    for slot in range(RUN_SLOTS):
        lock = (LOCK_DIR / f"slot-{slot}.lock").open("wb")
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            lock.close()
            continue
        return slot, lock
    raise RuntimeError(f"all {RUN_SLOTS} ROS domain slots are held by other test runs ({LOCK_DIR})")


@pytest.fixture(scope="session")
def _ros_domain_allocator() -> Iterator[Callable[[str], int]]:
    slot, lock = _lock_free_slot()
    first = 1 + slot * DOMAINS_PER_RUN
    allocated: dict[str, int] = {}

    def allocate(module: str) -> int:
        if module not in allocated:
            if len(allocated) == DOMAINS_PER_RUN:
                raise RuntimeError(f"more than {DOMAINS_PER_RUN} test modules need a ROS domain")
            allocated[module] = first + len(allocated)
        return allocated[module]

    try:
        yield allocate
    finally:
        lock.close()


@pytest.fixture(scope="module")
def ros_domain_id(request: pytest.FixtureRequest, _ros_domain_allocator: Callable[[str], int]) -> int:
    """This test module's DDS domain (1..100): give it to ``rclpy.init`` and to child processes."""
    return _ros_domain_allocator(request.module.__name__)
