# SPDX-License-Identifier: Apache-2.0
"""ament_python package definition; `colcon build` and `pip install` both use it."""

from setuptools import find_packages, setup

package_name = "suture_sim"

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
        "Stereo suture simulator with exact ground truth; writes MCAP bags and PNG training folders."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "suture-sim = suture_sim.cli:main",
            "suture-sim-bench = suture_sim.bench:main",
            "suture-bag-info = suture_sim.describe:main",
        ],
    },
)
