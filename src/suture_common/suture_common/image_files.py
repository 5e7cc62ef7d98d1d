# SPDX-License-Identifier: Apache-2.0
"""Image files of a folder: the one listing behind training folders and imported recordings."""

from __future__ import annotations

from pathlib import Path

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
"""File name endings read as images (compared in lower case)."""


def image_files(folder: str | Path, what: str = "image", error: type[Exception] = ValueError) -> list[Path]:
    """The image files (:data:`IMAGE_SUFFIXES`) of ``folder``, sorted by name.

    Raises ``error`` (the caller's exception type) naming ``what`` folder when ``folder`` is not
    a folder or holds no image.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise error(f"{what} folder {folder} does not exist or is not a folder")
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not paths:
        raise error(f"{what} folder {folder} holds no images ({', '.join(IMAGE_SUFFIXES)})")
    return paths
