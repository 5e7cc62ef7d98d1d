# SPDX-License-Identifier: Apache-2.0
"""ament_python package definition; `colcon build` and `pip install` both use it."""

from setuptools import find_packages, setup

package_name = "suture_segmentation"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    # The shipped checkpoints and their int8 exports (docs/results.md, "Segmentation").
    package_data={package_name: ["weights/*.pt", "weights/*.onnx"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="Suture grasping maintainers",
    maintainer_email="maintainers@suture-grasping.org",
    description=(
        "Suture segmentation stage: U-Net with transfer learning, inference backends, segmentation_node."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "suture-seg = suture_segmentation.cli:main",
            "segmentation_node = suture_segmentation.segmentation_node:main",
        ],
    },
)
