"""Builders of small, deliberately broken (or valid) sequences in ``tmp_path``."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest


def _texture(rng: np.random.Generator, h: int, w: int, color: bool) -> np.ndarray:
    img = cv2.GaussianBlur(rng.integers(0, 256, (h, w), dtype=np.uint8), (5, 5), 1.5)
    return cv2.merge([img, img[::-1], img[:, ::-1]]) if color else img


def write_tum(
    root: Path,
    n: int = 12,
    size: tuple[int, int] = (64, 48),
    depth: bool = True,
    right: bool = False,
    camera_yaml: str | None = "fx: 50\nfy: 51\ncx: 31.5\ncy: 23.5\nwidth: 64\nheight: 48\n",
    groundtruth: bool = True,
    t0: float = 1000.0,
    dt: float = 1 / 30,
    seed: int = 0,
) -> Path:
    """A valid TUM-layout sequence of ``n`` frames with rgb/depth/right lists and GT."""
    rng = np.random.default_rng(seed)
    w, h = size
    root.mkdir(parents=True, exist_ok=True)
    for sub in ("rgb", "depth", "right"):
        (root / sub).mkdir(exist_ok=True)
    ts = t0 + dt * np.arange(n)
    rgb_lines, depth_lines, right_lines = ["# timestamp filename"], ["# timestamp filename"], []
    for i, t in enumerate(ts):
        name = f"{t:.6f}.png"
        cv2.imwrite(str(root / "rgb" / name), _texture(rng, h, w, True))
        rgb_lines.append(f"{t:.6f} rgb/{name}")
        if depth:
            td = t + 0.004
            dname = f"{td:.6f}.png"
            cv2.imwrite(str(root / "depth" / dname), rng.integers(0, 20000, (h, w)).astype(np.uint16))
            depth_lines.append(f"{td:.6f} depth/{dname}")
        if right:
            cv2.imwrite(str(root / "right" / name), _texture(rng, h, w, True))
            right_lines.append(f"{t:.6f} right/{name}")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    if depth:
        (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    if right:
        (root / "right.txt").write_text("\n".join(right_lines) + "\n")
    if camera_yaml is not None:
        (root / "camera.yaml").write_text(camera_yaml)
    if groundtruth:
        tg = np.arange(t0 - 0.05, t0 + dt * n + 0.05, 0.01)
        lines = [f"{t:.4f} {0.1 * k:.4f} 0 0 0 0 0 1" for k, t in enumerate(tg)]
        (root / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    return root


@pytest.fixture
def make_tum():
    """``make_tum(root, **kw) -> Path``: write a small TUM sequence (see :func:`write_tum`)."""
    return write_tum


def write_kitti(root: Path, n: int = 6, stereo: bool = True, seed: int = 0) -> Path:
    """``root/sequences/00`` with calib P0/P1 (fx 100, baseline 0.5 m), times, images, poses."""
    rng = np.random.default_rng(seed)
    seq = root / "sequences" / "00"
    (seq / "image_0").mkdir(parents=True)
    if stereo:
        (seq / "image_1").mkdir()
    for i in range(n):
        cv2.imwrite(str(seq / "image_0" / f"{i:06d}.png"), _texture(rng, 40, 80, False))
        if stereo:
            cv2.imwrite(str(seq / "image_1" / f"{i:06d}.png"), _texture(rng, 40, 80, False))
    (seq / "calib.txt").write_text(
        "P0: 100 0 40 0 0 100 20 0 0 0 1 0\nP1: 100 0 40 -50 0 100 20 0 0 0 1 0\n"
    )
    np.savetxt(seq / "times.txt", 0.1 * np.arange(n))
    (root / "poses").mkdir()
    T = np.tile(np.eye(4)[:3].reshape(1, 12), (n, 1))
    T[:, 11] = np.arange(n)
    np.savetxt(root / "poses" / "00.txt", T)
    return seq


@pytest.fixture
def make_kitti():
    return write_kitti
