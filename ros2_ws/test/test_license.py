# SPDX-License-Identifier: Apache-2.0
"""The licence: Apache-2.0 in LICENSE, in every package.xml, and an SPDX line atop every source file."""

import re
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SPDX = "# SPDX-License-Identifier: Apache-2.0"


def test_license_file_is_apache_2():
    text = (REPO / "LICENSE").read_text()
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    assert "END OF TERMS AND CONDITIONS" in text


def test_every_package_declares_apache_2():
    manifests = sorted(REPO.glob("src/*/package.xml"))
    assert manifests
    for manifest in manifests:
        assert re.search(r"<license>\s*Apache-2\.0\s*</license>", manifest.read_text()), manifest


def test_every_source_file_carries_the_spdx_line():
    listed = subprocess.run(
        ["git", "ls-files", "*.py", "*.sh", ".ci/run"], cwd=REPO, capture_output=True, text=True, check=True
    ).stdout.split()
    assert len(listed) > 100
    missing = [name for name in listed if SPDX not in (REPO / name).read_text().splitlines()[:2]]
    assert not missing, f"no '{SPDX}' in the first two lines of: {missing}"
