# SPDX-License-Identifier: Apache-2.0
"""ament_python package definition; `colcon build` and `pip install` both use it."""

from setuptools import find_packages, setup

package_name = "suture_replay"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Suture grasping maintainers",
    maintainer_email="maintainers@suture-grasping.org",
    description=(
        "Bag replay and recording without rosbag2: player_node (with latency report) and recorder_node; "
        "suture-import (raw stereo recordings and their calibration into a rectified bag)."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "player_node = suture_replay.player_node:main",
            "recorder_node = suture_replay.recorder_node:main",
            "suture-import = suture_replay.importer:main",
        ],
    },
)
