# SPDX-License-Identifier: Apache-2.0
"""ament_python package definition; `colcon build` and `pip install` both use it."""

from setuptools import find_packages, setup

package_name = "suture_bench"

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
    description="Offline evaluation and benchmarks over MCAP bags (suture-eval); depends on every stage.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "suture-eval = suture_bench.cli:main",
            "suture-eval-compare = suture_bench.compare:main",
            "suture-fewshot = suture_bench.fewshot:main",
            "suture-graph-report = suture_bench.graph_report:main",
            "suture-recon-bench = suture_bench.reconstruction_metrics:main",
            "suture-order-bench = suture_bench.ordering_bench:main",
        ],
    },
)
