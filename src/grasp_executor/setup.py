# SPDX-License-Identifier: Apache-2.0
"""ament_python package definition; `colcon build` and `pip install` both use it."""

from setuptools import find_packages, setup

package_name = "grasp_executor"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", ["config/executor.yaml", "config/hand_eye_example.yaml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Suture grasping maintainers",
    maintainer_email="maintainers@suture-grasping.org",
    description=(
        "Grasp executor: safety checks and dry_run, dVRK (CRTK) and UR (ur_rtde) backends, executor_node."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "executor_node = grasp_executor.executor_node:main",
            "psm_sim_node = grasp_executor.psm_sim_node:main",
        ],
    },
)
