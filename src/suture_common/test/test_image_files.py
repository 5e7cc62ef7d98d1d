# SPDX-License-Identifier: Apache-2.0
"""image_files: a folder's images sorted by name, or the caller's error naming the folder."""

import pytest

from suture_common.image_files import image_files


class CallerError(ValueError):
    pass


def test_images_sorted_by_name_other_files_left_out(tmp_path):
    for name in ("b.PNG", "a.jpg", "notes.txt", "c.tiff"):
        (tmp_path / name).write_bytes(b"")
    assert [p.name for p in image_files(tmp_path)] == ["a.jpg", "b.PNG", "c.tiff"]


def test_a_missing_or_empty_folder_raises_the_callers_error(tmp_path):
    with pytest.raises(CallerError, match="left folder .* does not exist or is not a folder"):
        image_files(tmp_path / "nope", "left", CallerError)
    with pytest.raises(CallerError, match="masks folder .* holds no images"):
        image_files(tmp_path, "masks", CallerError)
