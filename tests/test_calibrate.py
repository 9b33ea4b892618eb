"""``vslam calibrate`` on rendered board images with known intrinsics (pinhole+radtan, fisheye, ChArUco)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from vslam.calibrate import Board, calibrate_views
from vslam.cli import main
from vslam.datasets.calibration import read_camera_file

W, H = 640, 480
K = np.array([[500.0, 0, 322.0], [0, 505.0, 238.0], [0, 0, 1]])
RADTAN = np.array([-0.12, 0.05, 0.001, -0.0005, 0.0])
FISH = np.array([0.08, -0.02, 0.004, -0.001])


def _board_texture(board: Board, px: int = 40):
    """The board image and the map from texture pixels to board-plane metres (3x3)."""
    margin = px
    if board.charuco:
        img = board.charuco_board().generateImage((board.cols * px + 2 * margin, board.rows * px + 2 * margin),
                                                  marginSize=margin)
        origin = margin + px  # ChArUco corner 0 is one square in
    else:
        nx, ny = board.cols + 1, board.rows + 1
        img = np.full((ny * px + 2 * margin, nx * px + 2 * margin), 255, np.uint8)
        for j in range(ny):
            for i in range(nx):
                if (i + j) % 2 == 0:
                    img[margin + j * px: margin + (j + 1) * px, margin + i * px: margin + (i + 1) * px] = 0
        origin = margin + px
    s = board.square / px
    A = np.array([[s, 0, -(origin - 0.5) * s], [0, s, -(origin - 0.5) * s], [0, 0, 1]])
    return img, A


def _render(board: Board, n: int, dist=None, fisheye=False, seed=0, xy=None, tilt=0.45):
    """Views of the board from poses around it, through K and the lens model; ``xy``: the board
    centre's ``(x, y)`` in the camera (metres) of each view instead of random ones; ``tilt``: the
    largest rotation about x and y (radians)."""
    rng = np.random.default_rng(seed)
    n = n if xy is None else len(xy)
    tex, A = _board_texture(board)
    n_c, n_r = (board.cols - 1, board.rows - 1) if board.charuco else (board.cols, board.rows)
    centre = np.array([(n_c - 1) * board.square / 2, (n_r - 1) * board.square / 2, 0])
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    pix = np.stack([xs.ravel(), ys.ravel()], 1).reshape(-1, 1, 2)
    if fisheye:
        und = cv2.fisheye.undistortPoints(pix.astype(np.float64), K, dist, P=K)
    elif dist is not None:
        und = cv2.undistortPointsIter(pix, K, dist, None, K, (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-8))
    else:
        und = pix
    mapx, mapy = (und.reshape(H, W, 2)[..., k].astype(np.float32) for k in (0, 1))
    views = []
    for k in range(n):
        rvec = rng.uniform(-tilt, tilt, 3) * np.array([1, 1, 0.4])
        R = cv2.Rodrigues(rvec)[0]
        dist_z = rng.uniform(0.45, 0.65) if fisheye else rng.uniform(0.55, 0.8)
        x, y = (rng.uniform(-0.22, 0.22), rng.uniform(-0.15, 0.15)) if xy is None else xy[k]
        t = np.array([x, y, dist_z]) - R @ centre
        Hm = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ A  # texture pixel -> ideal image pixel
        ideal = cv2.warpPerspective(tex, Hm, (W, H), flags=cv2.INTER_LINEAR, borderValue=200)
        img = cv2.remap(ideal, mapx, mapy, cv2.INTER_LINEAR, borderValue=200)
        views.append((f"view{k:02d}", cv2.GaussianBlur(img, (3, 3), 0.6)))
    return views


def test_checkerboard_radtan_within_one_percent():
    board = Board(9, 6, 0.03)
    res = calibrate_views(_render(board, 20, RADTAN), board)
    c = res.camera
    assert res.model == "radtan" and len(res.view_rms) >= 12
    assert abs(c.fx / 500.0 - 1) < 0.01 and abs(c.fy / 505.0 - 1) < 0.01  # measured 500.44, 505.55
    assert abs(c.cx - 322) < 3 and abs(c.cy - 238) < 3
    # the lens model agrees with the true one over the image (k1..k3 trade off; the mapping must not)
    pts = np.array([[100.0, 80.0], [540.0, 400.0], [320.0, 60.0], [100.0, 400.0]]).reshape(-1, 1, 2)
    true = cv2.undistortPoints(pts, K, RADTAN, P=K).reshape(-1, 2)
    est = cv2.undistortPoints(pts, c.K, c.dist_coeffs, P=K).reshape(-1, 2)
    assert np.abs(est - true).max() < 2.5  # measured 1.8 px (radtan), 0.8 px (fisheye), mostly the cx, cy offset
    assert 0.05 < res.rms < 0.4  # measured 0.175 px


def test_fisheye_and_cli_roundtrip(tmp_path, capsys):
    board = Board(9, 6, 0.03)
    folder = tmp_path / "views"
    folder.mkdir()
    for name, img in _render(board, 20, FISH, fisheye=True, seed=1):
        cv2.imwrite(str(folder / f"{name}.png"), img)
    out = tmp_path / "camera.yaml"
    assert main(["calibrate", str(folder), "--board", "9x6", "--square", "0.03", "--fisheye", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "RMS reprojection error" in text and "model equidistant" in text
    cal = read_camera_file(out)
    assert cal.model == "equidistant" and cal.format == "vslam"
    assert abs(cal.camera.fx / 500.0 - 1) < 0.01 and abs(cal.camera.fy / 505.0 - 1) < 0.01
    pts = np.array([[100.0, 80.0], [540.0, 400.0], [320.0, 240.0]]).reshape(-1, 1, 2)
    true = cv2.fisheye.undistortPoints(pts, K, FISH, P=K).reshape(-1, 2)
    est = cv2.fisheye.undistortPoints(pts, cal.camera.K, np.array(cal.camera.dist), P=K).reshape(-1, 2)
    assert np.abs(est - true).max() < 2.5  # measured 1.8 px (radtan), 0.8 px (fisheye), mostly the cx, cy offset
    assert main(["calibrate", str(folder), "--board", "7x4", "--square", "0.03", "-o", str(out)]) == 2
    assert "was found in 0 views" in capsys.readouterr().err


def test_charuco_within_one_percent():
    board = Board(7, 5, 0.04, charuco="DICT_5X5_100")
    res = calibrate_views(_render(board, 20, None, seed=2), board)  # measured fx 498.07, fy 502.94
    assert abs(res.camera.fx / 500.0 - 1) < 0.01 and abs(res.camera.fy / 505.0 - 1) < 0.01


GRID_XY = [(x, y) for y in (-0.15, 0.0, 0.15) for x in (-0.22, 0.0, 0.22)]  # the board over a 3x3 grid at ~0.65 m


def test_views_over_the_whole_image_give_no_warning(capsys):
    board = Board(9, 6, 0.03)
    res = calibrate_views(_render(board, 0, RADTAN, seed=3, xy=GRID_XY * 2, tilt=0.2), board)
    assert len(res.view_rms) == 18 and res.warnings == []
    assert abs(res.camera.fx / 500.0 - 1) < 0.01
    lines = res.summary().splitlines()
    assert "per-view RMS reprojection error [px]:" in lines and not any(l.startswith("warning") for l in lines)
    per_view = [l for l in lines if l.startswith("  view")]
    assert len(per_view) == 18 and all(0 < float(l.split(":")[1].split()[0]) < 1 for l in per_view)


def test_views_in_one_part_of_the_image_are_named_and_more_views_asked_for(tmp_path, capsys):
    """Every view shows the board in the top-left of the image: the uncovered cells are named."""
    board = Board(9, 6, 0.03)
    folder = tmp_path / "views"
    folder.mkdir()
    xy = [(x, y) for x in (-0.22, -0.17, -0.12) for y in (-0.15, -0.11, -0.06)]
    for name, img in _render(board, 0, RADTAN, seed=4, xy=xy, tilt=0.2):
        cv2.imwrite(str(folder / f"{name}.png"), img)
    out = tmp_path / "camera.yaml"
    assert main(["calibrate", str(folder), "--board", "9x6", "--square", "0.03", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert len([l for l in text.splitlines() if l.startswith("  view")]) == 9
    cover = [l for l in text.splitlines() if l.startswith("warning: the views cover")]
    assert len(cover) == 1
    missing = cover[0].split("no board seen in the ")[1].split(", ")
    assert {"right edge", "bottom-right corner", "bottom edge", "top-right corner"} <= set(missing)
    assert "top-left corner" not in missing
    assert "warning: only 9 views with the board" in text
    advice = [l for l in text.splitlines() if l.startswith("warning: take more views")]
    assert len(advice) == 1 and "bottom-right corner" in advice[0]
    assert read_camera_file(out).camera.fx > 0  # still written: the warnings do not stop it


def test_principal_point_and_distortion_checks():
    from vslam.calibrate import quality_warnings
    from vslam.geometry.camera import PinholeCamera

    full = [np.array([[0, 0], [W, 0], [0, H], [W, H]], float)] * 12  # views covering the whole image
    good = PinholeCamera(458.7, 457.3, 367.2, 248.4, 752, 480, (-0.2834, 0.0740, 0.0002, 0.00002, 0.0))  # EuRoC cam0
    assert quality_warnings(good, "radtan", full, (752, 480)) == []
    fish = PinholeCamera(500, 505, 322, 238, W, H, tuple(FISH))
    assert quality_warnings(fish, "equidistant", full, (W, H)) == []
    off = PinholeCamera(500, 505, 322 + 80, 238, W, H, tuple(RADTAN))  # 12.5 % of the width off
    w = quality_warnings(off, "radtan", full, (W, H))
    assert w[0].startswith("principal point (402.0, 238.0) is 13 % of the width") and w[-1].startswith("take more")
    assert len(w) == 2
    wild = PinholeCamera(500, 505, 322, 238, W, H, (-2.5, 0.3, 0.0, 0.08, 0.0))
    w = quality_warnings(wild, "radtan", full, (W, H))
    assert len(w) == 2 and w[0].startswith("distortion terms are extreme (k1 -2.5, p2 0.08; the radial model folds")
    assert "k2" not in w[0]
