# SPDX-License-Identifier: Apache-2.0
"""The workspace is a real ROS 2 workspace: ament_python packages that colcon builds, whose
installed executables run the way ``ros2 run PKG EXE`` runs them on a full install."""

from __future__ import annotations

import os
import shutil
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = sorted(p.parent for p in (ROOT / "src").glob("*/package.xml"))
STAGES = {"suture_segmentation", "suture_ordering", "suture_reconstruction", "grasp_executor"}


def test_layout_has_every_stage_and_the_tools():
    names = {p.name for p in PACKAGES}
    assert STAGES | {"suture_common", "suture_sim", "suture_bench"} <= names
    for folder in ("bags", "docker", "ros2_ws"):
        assert (ROOT / folder).is_dir()


@pytest.mark.parametrize("package", PACKAGES, ids=lambda p: p.name)
def test_package_is_ament_python(package):
    manifest = ET.parse(package / "package.xml").getroot()
    assert manifest.get("format") == "3"
    assert manifest.findtext("name") == package.name
    assert manifest.find("export/build_type").text == "ament_python"
    assert (package / "resource" / package.name).is_file()
    assert (package / package.name / "__init__.py").is_file()
    assert f"$base/lib/{package.name}" in (package / "setup.cfg").read_text()
    assert "console_scripts" in (package / "setup.py").read_text()


def test_colcon_builds_the_workspace_and_installed_executables_run(tmp_path):
    colcon = Path(os.environ.get("VIRTUAL_ENV", ROOT / ".venv")) / "bin" / "colcon"
    if not colcon.exists():
        colcon = Path(shutil.which("colcon") or "colcon")
    build = subprocess.run(
        [
            str(colcon),
            "--log-base",
            str(tmp_path / "log"),
            "build",
            "--base-paths",
            str(ROOT / "src"),
            "--build-base",
            str(tmp_path / "build"),
            "--install-base",
            str(tmp_path / "install"),
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert build.returncode == 0, build.stdout[-2000:] + build.stderr[-2000:]
    assert f"{len(PACKAGES)} packages finished" in build.stdout
    executable = tmp_path / "install" / "suture_sim" / "lib" / "suture_sim" / "suture-sim"
    assert (tmp_path / "install" / "setup.bash").is_file()
    run = subprocess.run(
        ["bash", "-c", f"source {tmp_path / 'install' / 'setup.bash'} && {executable} --help"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0 and "--topology" in run.stdout, run.stderr
