"""Jacquard reader, and a measured check of its axis and angle convention against the masks."""

import math
import shutil

import numpy as np
import pytest

from kosmos_jax import geometry
from kosmos_jax.sources import jacquard


def chord_midpoint_offset(mask, centre, direction):
    """Signed distance from `centre` to the middle of the mask run through it along `direction`
    (None when the centre is off the mask), sampled every half pixel."""
    height, width = mask.shape
    steps = np.arange(-400, 400.5, 0.5)
    points = centre[None] + steps[:, None] * direction[None]
    cols = np.clip(np.round(points[:, 0]).astype(int), 0, width - 1)
    rows = np.clip(np.round(points[:, 1]).astype(int), 0, height - 1)
    inside = mask[rows, cols]
    middle = len(steps) // 2
    if not inside[middle]:
        return None
    lo = middle
    while lo > 0 and inside[lo - 1]:
        lo -= 1
    hi = middle
    while hi < len(steps) - 1 and inside[hi + 1]:
        hi += 1
    return (steps[lo] + steps[hi]) / 2


def opening_axes(grasps):
    corners = geometry.grasps_to_corners(grasps)
    axis = corners[:, 1] - corners[:, 0]
    return axis / np.linalg.norm(axis, axis=-1, keepdims=True)


def test_files_found_and_counted(jacquard_root):
    files = jacquard.find_photos(jacquard_root)
    assert len(files) == 10
    assert [f.id for f in files] == sorted(f.id for f in files)
    for f in files:
        lines = [l for l in f.grasps.read_bytes().split(b"\r\n") if l.strip()]
        photo = jacquard.read_photo(f, load_images=False)
        assert photo.grasps.shape == (len(lines), 5)
        assert photo.object_id == f.id.split("_", 1)[1]
        first = [float(v) for v in lines[0].decode().split(";")]
        np.testing.assert_allclose(photo.grasps[0], [first[0], first[1], first[3], first[4],
                                                     geometry.normalize_angle(-math.radians(first[2]))])


def test_images_and_depth(jacquard_root):
    photo = jacquard.load_photos(jacquard_root)[0]
    assert photo.rgb.shape == (1024, 1024, 3) and photo.rgb.dtype == np.uint8
    assert photo.depth.shape == (1024, 1024) and photo.depth.dtype == np.float32
    assert np.isfinite(photo.depth).all() and photo.depth.min() > 0  # perfect depth: no holes
    stereo = jacquard.read_photo(jacquard.find_photos(jacquard_root)[0], depth="stereo")
    assert (stereo.depth == -1).any()  # the stereo depth marks holes with -1


def test_centres_lie_on_the_mask_with_x_as_column(jacquard_root):
    on, swapped = [], []
    for f in jacquard.find_photos(jacquard_root):
        mask = jacquard.read_mask(f)
        g = jacquard.read_photo(f, load_images=False).grasps
        x, y = np.round(g[:, 0]).astype(int), np.round(g[:, 1]).astype(int)
        on.append(mask[y, x])
        swapped.append(mask[x.clip(0, 1023), y.clip(0, 1023)])
    assert np.concatenate(on).mean() == 1.0
    assert np.concatenate(swapped).mean() < 0.3


def test_angle_sign_centres_the_grasp_along_its_opening_axis(jacquard_root):
    """A parallel-jaw grasp sits mid-object along its closing axis. Our conversion (theta negated)
    must put the centre nearer the middle of the mask chord than the mirrored sign does."""
    ours, mirrored, per_view = [], [], {}
    for f in jacquard.find_photos(jacquard_root):
        mask = jacquard.read_mask(f)
        grasps = np.unique(jacquard.read_photo(f, load_images=False).grasps[:, [0, 1, 2, 4]], axis=0)
        grasps = np.concatenate([grasps[:, :3], np.ones((len(grasps), 1)), grasps[:, 3:]], axis=1)
        flipped = grasps.copy()
        flipped[:, 4] = -flipped[:, 4]
        a = [abs(chord_midpoint_offset(mask, g[:2], u)) for g, u in zip(grasps, opening_axes(grasps))]
        b = [abs(chord_midpoint_offset(mask, g[:2], u)) for g, u in zip(flipped, opening_axes(flipped))]
        ours += a
        mirrored += b
        per_view[f.id] = (np.median(a), np.median(b))
    ours, mirrored = np.array(ours), np.array(mirrored)
    assert len(ours) == 118
    assert np.median(ours) < np.median(mirrored)
    assert np.mean(ours < mirrored) > 2 * np.mean(ours > mirrored)
    # The elongated object (ffe7...) decides it view by view; the ball (2f48...) cannot.
    for photo_id, (a, b) in per_view.items():
        if photo_id.startswith(tuple(f"{n}_ffe7" for n in range(5))):
            assert a < b / 2, (photo_id, a, b)


def test_row_conversion_round_trip():
    rows = np.array([[10.0, 20.0, -36.6749, 175.5, 26.6], [5.0, 6.0, 90.0, 10.0, 3.0],
                     [1.0, 2.0, 0.0, 4.0, 5.0]])
    back = jacquard.grasps_to_rows(jacquard.rows_to_grasps(rows))
    same = geometry.angle_difference(np.radians(back[:, 2]), np.radians(rows[:, 2]))
    np.testing.assert_allclose(back[:, [0, 1, 3, 4]], rows[:, [0, 1, 3, 4]])
    np.testing.assert_allclose(same, 0, atol=1e-12)
    # +30 degrees in Jacquard is clockwise on screen: the opening axis points right and DOWN.
    u = opening_axes(jacquard.rows_to_grasps(np.array([[0, 0, 30.0, 2, 1]])))[0]
    assert u[0] * u[1] > 0  # x and y (down) share a sign


@pytest.mark.parametrize("text, line", [
    ("1;2;3;4;5\r\n1;2;3;4\r\n", 2),
    ("1;2;3;4;5\r\n\r\n1;2;x;4;5\r\n", 3),
    ("1;2;nan;4;5\n", 1),
])
def test_malformed_grasps_name_file_and_line(tmp_path, text, line):
    path = tmp_path / "0_abc_grasps.txt"
    path.write_bytes(text.encode())
    with pytest.raises(jacquard.JacquardFormatError) as error:
        jacquard.read_grasps(path)
    assert str(path) in str(error.value) and f"line {line}" in str(error.value)


def test_corrupt_rgb_names_file(tmp_path, jacquard_root):
    source = jacquard.find_photos(jacquard_root)[0]
    shutil.copy(source.grasps, tmp_path)
    (tmp_path / f"{source.id}_RGB.png").write_bytes(b"\x89PNG broken")
    with pytest.raises(jacquard.JacquardFormatError, match="_RGB.png"):
        jacquard.load_photos(tmp_path)
    assert jacquard.load_photos(tmp_path, load_images=False)[0].grasps.shape[0] > 0


def test_broken_copies_of_real_grasps_name_file_and_line(tmp_path, jacquard_root):
    source = jacquard.find_photos(jacquard_root)[0].grasps
    lines = source.read_bytes().split(b"\r\n")
    path = tmp_path / source.name
    bad = list(lines)
    bad[2] = b"\xe9" + bad[2]  # line 3, column 1
    path.write_bytes(b"\r\n".join(bad))
    with pytest.raises(jacquard.JacquardFormatError, match=rf"{path.name}, line 3, column 1: not UTF-8 text"):
        jacquard.read_grasps(path)
    bad = list(lines)
    fields = bad[4].split(b";")
    bad[4] = b";".join([fields[0], b"1_0", *fields[2:]])  # float() would read 10
    path.write_bytes(b"\r\n".join(bad))
    with pytest.raises(jacquard.JacquardFormatError, match=rf"{path.name}, line 5: not a number"):
        jacquard.read_grasps(path)
    bad = list(lines)
    bad[6] = bad[6] + b"\x0c"  # a form feed is no line break: the line is malformed, and it is line 7
    path.write_bytes(b"\r\n".join(bad))
    with pytest.raises(jacquard.JacquardFormatError, match=rf"{path.name}, line 7: not a number"):
        jacquard.read_grasps(path)
