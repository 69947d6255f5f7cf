"""Cornell point clouds (pcdNNNN.txt) -> GG-CNN depth images (pcdNNNNd.tiff): kosmos_jax.sources.cornell_depth."""

import pathlib
import subprocess
import sys

import cv2
import numpy as np
import pytest

from kosmos_jax.sources import cornell, cornell_depth

REPO = pathlib.Path(__file__).resolve().parents[1]
HEIGHT, WIDTH = cornell_depth.SHAPE
# Cornell's header, copied from a pcdNNNN.txt of the data set (its point lines look like
# "1924.064 -647.111 -119.4176 0 25547": x y z in millimetres, rgb, index = row * 640 + column).
HEADER = """# .PCD v.7 - Point Cloud Data file format
FIELDS x y z rgb index
SIZE 4 4 4 4 4
TYPE F F F F U
COUNT 1 1 1 1 1
WIDTH {n}
HEIGHT 1
VIEWPOINT 0 0 0 1 0 0 0
POINTS {n}
DATA ascii
"""
MISSING = [(0, 0), (479, 639), (100, 100), (200, 260), (300, 500), (50, 50), (50, 51), (51, 50), (51, 51)]
# A present pixel's depth is rounded to float32 twice: its coordinates when read (relative error
# <= 2^-24 each, so <= 2^-24 on their Euclidean norm, which is 1-Lipschitz), and the depth when
# stored (<= 2^-24). The float64 arithmetic in between (squares, sum, sqrt, / 1000, and the
# test's own back-projection printed with repr, which round-trips) adds ~1e-15.
RTOL = 2 * 2.0**-24 + 2.0**-48 + 1e-14


def known_depth() -> np.ndarray:
    """A tilted table (0.7 to 0.95 m) with a box 8 cm nearer on it; float32 metres, MISSING at 0."""
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH]
    depth = 0.7 + 0.0004 * rows + 0.0001 * cols
    depth[200:280, 260:380] -= 0.08  # (200, 260) is missing: its neighbours lie on both levels
    depth = depth.astype(np.float32)
    for pixel in MISSING:
        depth[pixel] = 0
    return depth


def point_lines(depth: np.ndarray) -> list[str]:
    """Each pixel with a depth back-projected through a pinhole (x forward, as Cornell's clouds) to
    millimetres at that distance; shuffled, as the order of the lines carries nothing."""
    rows, cols = np.nonzero(depth)
    rays = np.stack([np.full(rows.shape, 600.0), cols - 319.5, rows - 239.5], axis=1)
    points = rays / np.linalg.norm(rays, axis=1, keepdims=True) * depth[rows, cols, None].astype(np.float64) * 1000
    order = np.random.default_rng(0).permutation(len(rows))
    return [f"{x!r} {y!r} {z!r} 0 {r * WIDTH + c}" for (x, y, z), r, c in zip(points[order].tolist(),
                                                                           rows[order], cols[order])]


def write_pcd(path: pathlib.Path, lines: list[str], header: str | None = None) -> pathlib.Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    header = HEADER.format(n=len(lines)) if header is None else header
    path.write_text(header + "".join(line + "\n" for line in lines))
    return path


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    depth = known_depth()
    path = write_pcd(tmp_path_factory.mktemp("cloud") / "pcd0100.txt", point_lines(depth))
    return depth, path


def assert_known_depth(result, depth):
    present = depth != 0
    assert result.dtype == np.float32 and result.shape == (HEIGHT, WIDTH)
    np.testing.assert_allclose(result[present], depth[present], rtol=RTOL, atol=0)
    for row, col in MISSING:  # filled within the range of the present pixels around it
        window = depth[max(row - 1, 0):row + 2, max(col - 1, 0):col + 2]
        around = window[window != 0]
        assert around.min() * (1 - 1e-6) <= result[row, col] <= around.max() * (1 + 1e-6), (row, col)


def test_functions_recover_the_known_depth(scene):
    depth, path = scene
    points, index = cornell_depth.read_pcd(path)
    assert points.dtype == np.float32 and points.shape == (HEIGHT * WIDTH - len(MISSING), 3)
    raw = cornell_depth.depth_image(points, index)
    assert np.array_equal(raw == 0, depth == 0)
    assert_known_depth(cornell_depth.inpaint_missing(raw), depth)


def test_inpainting_follows_gg_cnn_steps():
    """GG-CNN's inpaint: pad 1 pixel (BORDER_DEFAULT), mask = padded == 0, divide by the max |depth|,
    cv2.inpaint(radius 1, INPAINT_NS) in float32, crop, multiply back."""
    depth = known_depth()
    padded = cv2.copyMakeBorder(depth.astype(np.float64), 1, 1, 1, 1, cv2.BORDER_DEFAULT)
    scale = np.abs(padded).max()
    steps = cv2.inpaint((padded / scale).astype(np.float32), (padded == 0).astype(np.uint8), 1, cv2.INPAINT_NS)
    gg_cnn = (steps[1:-1, 1:-1] * scale).astype(np.float32)
    # present pixels: GG-CNN's / scale and * scale round to float32 once more each, 2^-24 at most
    np.testing.assert_allclose(cornell_depth.inpaint_missing(depth), gg_cnn, rtol=4 * 2.0**-24, atol=0)


def test_cornell_point_lines_give_distance_in_metres_at_row_and_column(tmp_path):
    lines = ["1924.064 -647.111 -119.4176 0 25547", "1924.412 -649.678 -119.7147 0 25548"]
    points, index = cornell_depth.read_pcd(write_pcd(tmp_path / "pcd0100.txt", lines))
    depth = cornell_depth.depth_image(points, index)
    assert np.count_nonzero(depth) == 2  # 25547 = 39 * 640 + 587
    expected = np.float32(np.sqrt(1924.064**2 + 647.111**2 + 119.4176**2) / 1000)
    np.testing.assert_allclose(depth[39, 587], expected, rtol=RTOL)


def test_repeated_index_keeps_the_last_point_and_nan_is_missing():
    points = np.array([[1000, 0, 0], [2000, 0, 0], [np.nan, 0, 0]], np.float32)
    depth = cornell_depth.depth_image(points, np.array([5, 5, 7]))
    assert depth.reshape(-1)[5] == 2.0 and depth.reshape(-1)[7] == 0


def test_command_writes_tiffs_the_cornell_reader_loads(scene, tmp_path):
    depth, cloud = scene
    first = tmp_path / "01" / "pcd0100.txt"
    first.parent.mkdir()
    first.write_bytes(cloud.read_bytes())
    nested = write_pcd(tmp_path / "02" / "more" / "pcd0200.txt", point_lines(depth)[:1000])
    cv2.imwrite(str(tmp_path / "01" / "pcd0100r.png"), np.zeros((HEIGHT, WIDTH, 3), np.uint8))
    cornell.write_rectangles(tmp_path / "01" / "pcd0100cpos.txt", np.array([[320, 240, 40, 20, 0.3]]))
    command = [sys.executable, "-m", "kosmos_jax.sources.cornell_depth", str(tmp_path)]

    run = subprocess.run(command, capture_output=True, text=True, cwd=REPO)
    assert run.returncode == 0, run.stderr
    summary = f"2 depth images written, 0 existing kept, from 2 point clouds under {tmp_path}"
    assert run.stdout.splitlines() == [summary]
    assert "[2/2] wrote" in run.stderr
    photo, = cornell.load_photos(tmp_path, object_map=None)
    assert_known_depth(photo.depth, depth)
    assert cornell.read_depth(nested.with_name("pcd0200d.tiff")).shape == (HEIGHT, WIDTH)
    assert not list(tmp_path.rglob("*.part"))

    written = (tmp_path / "01" / "pcd0100d.tiff").stat().st_mtime_ns
    again = subprocess.run(command, capture_output=True, text=True, cwd=REPO)
    assert again.stdout.startswith("0 depth images written, 2 existing kept")
    assert (tmp_path / "01" / "pcd0100d.tiff").stat().st_mtime_ns == written
    forced = subprocess.run(command + ["--overwrite"], capture_output=True, text=True, cwd=REPO)
    assert forced.returncode == 0 and forced.stdout.startswith("2 depth images written")


GOOD = ["1924.064 -647.111 -119.4176 0 25547", "1924.412 -649.678 -119.7147 0 25548"]
BROKEN = {
    "truncated": (HEADER.format(n=3), GOOD, "truncated: 2 point lines, the header says 3"),
    "cut mid-line": (HEADER.format(n=2), GOOD[:1] + ["1924.412 -649.6"],
                     "line 12: expected 5 values a point, got 2"),
    "no header": ("", GOOD, "line 1: not a PCD header line"),
    "no index field": (HEADER.format(n=2).replace(" index", ""), [g.rsplit(" ", 1)[0] for g in GOOD],
                       "FIELDS x y z rgb: needs x y z ... index"),
    "binary": (HEADER.format(n=2).replace("ascii", "binary"), GOOD, "DATA binary: only ascii PCD is read"),
    "index outside": (HEADER.format(n=2), GOOD[:1] + ["1924.412 -649.678 -119.7147 0 307200"],
                      "line 12: pixel index 307200 is not a pixel of the 480x640 image"),
}


@pytest.mark.parametrize("case", BROKEN)
def test_broken_point_cloud_is_one_clear_error(case, tmp_path, capsys):
    header, lines, message = BROKEN[case]
    path = write_pcd(tmp_path / "01" / "pcd0100.txt", lines, header=header)
    assert cornell_depth.main([str(tmp_path)]) == 1
    error = capsys.readouterr().err.splitlines()[-1]
    assert error.startswith(f"error: {path}") and message in error
    assert list(path.parent.iterdir()) == [path]


def test_empty_folder_is_an_error(tmp_path):
    (tmp_path / "01").mkdir()
    (tmp_path / "01" / "pcd0100cpos.txt").write_text("")  # rectangles, not a point cloud
    run = subprocess.run([sys.executable, "-m", "kosmos_jax.sources.cornell_depth", str(tmp_path)],
                         capture_output=True, text=True, cwd=REPO)
    assert run.returncode == 1 and run.stdout == ""
    assert run.stderr.splitlines() == [f"error: {tmp_path}: no pcdNNNN.txt point clouds under it"]


def test_interrupted_write_leaves_no_file(tmp_path, monkeypatch):
    path = write_pcd(tmp_path / "pcd0100.txt", GOOD)

    def interrupted(file, image, **kwargs):
        file.write(b"II*\x00")
        raise KeyboardInterrupt

    monkeypatch.setattr(cornell_depth.tifffile, "imwrite", interrupted)
    with pytest.raises(KeyboardInterrupt):
        cornell_depth.convert(path)
    assert list(tmp_path.iterdir()) == [path]


@pytest.mark.shared_data
def test_matches_the_shared_depth_images(cornell_root):
    clouds = [p for p in sorted(cornell_root.rglob("pcd*.txt"))
              if cornell_depth.POINT_CLOUD_NAME.fullmatch(p.name) and cornell_depth.depth_path(p).exists()]
    if not clouds:
        pytest.skip("../shared/data/cornell holds no pcdNNNN.txt point cloud beside a pcdNNNNd.tiff "
                    "(only the GG-CNN depth images), so there is nothing to compare")
    raw = cornell_depth.depth_image(*cornell_depth.read_pcd(clouds[0]))
    depth, present = cornell_depth.inpaint_missing(raw), raw != 0
    reference = cornell.read_depth(cornell_depth.depth_path(clouds[0]))
    # GG-CNN rounds each present depth through float32 twice more (/ scale, * scale around inpainting)
    np.testing.assert_allclose(depth[present], reference[present], rtol=4 * 2.0**-24)
    np.testing.assert_allclose(depth, reference, atol=1e-3)  # inpainted pixels: OpenCV versions may differ
