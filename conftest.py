"""Repository-wide pytest set-up: property tests are derandomised under CI, so a submission's
CI run tries exactly the examples that `CI=true bash ros2_ws/test.sh` tried locally."""

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")
