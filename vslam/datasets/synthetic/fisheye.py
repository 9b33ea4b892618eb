"""Render the synthetic scene through a fisheye (Kannala-Brandt / equidistant) lens.

The ray-cast renderer is pinhole only, so a fisheye image is made in two steps: render a pinhole
image wide enough to hold every ray of the fisheye image, then resample it at the pinhole pixel of
each fisheye pixel's ray. The ray of fisheye pixel ``(u, v)`` is ``cv2.fisheye.undistortPoints``
of it, i.e. the inverse of the equidistant model ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 +
k3 theta^6 + k4 theta^8)``, ``r = f theta_d`` (Kannala & Brandt, PAMI 2006, eq. 6, as OpenCV's
``cv2.fisheye``); on the wide pinhole image it lands at ``(fp x + cpx, fp y + cpy)``. Both cameras
share the centre and axes, so the fisheye camera's pose is the pinhole pose and depth (z along
the optical axis) carries over unchanged.

Example::

    lens = FisheyeLens(K, D, (320, 240))
    image, depth = lens.render(renderer, T_world_cam)
"""
from __future__ import annotations

import cv2
import numpy as np

from vslam.datasets.synthetic.renderer import Renderer
from vslam.geometry.camera import PinholeCamera


class FisheyeLens:
    """A fisheye camera ``K`` (3x3), ``D`` (k1..k4), ``size`` (W, H) rendered via a wide pinhole image.

    Args:
        oversample: focal length of the wide pinhole render relative to the fisheye's ``fx`` (1.0
            samples the image centre at the fisheye's resolution; the periphery is then
            oversampled, since the fisheye compresses it).
    """

    def __init__(self, K: np.ndarray, D, size: tuple[int, int], oversample: float = 1.05) -> None:
        self.K = np.asarray(K, dtype=np.float64)
        self.D = np.asarray(D, dtype=np.float64).reshape(4)
        self.size = (int(size[0]), int(size[1]))
        w, h = self.size
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        xy = cv2.fisheye.undistortPoints(np.stack([u, v], -1).reshape(-1, 1, 2), self.K, self.D).reshape(h, w, 2)
        if not np.all(np.isfinite(xy)):
            raise ValueError("the fisheye model does not invert over the whole image; use a smaller distortion")
        fp = float(oversample) * float(self.K[0, 0])
        xmax, ymax = np.abs(xy[..., 0]).max(), np.abs(xy[..., 1]).max()
        wp, hp = int(np.ceil(2 * xmax * fp)) + 4, int(np.ceil(2 * ymax * fp)) + 4
        #: the wide pinhole camera that is rendered and resampled
        self.pinhole = PinholeCamera(fp, fp, (wp - 1) / 2.0, (hp - 1) / 2.0, wp, hp)
        self.map_x = (fp * xy[..., 0] + self.pinhole.cx).astype(np.float32)
        self.map_y = (fp * xy[..., 1] + self.pinhole.cy).astype(np.float32)
        #: half field of view (radians) along x and y at the image borders
        self.half_fov = (float(np.arctan(xmax)), float(np.arctan(ymax)))

    def warp(self, image: np.ndarray, nearest: bool = False) -> np.ndarray:
        """Resample a render of :attr:`pinhole` into the fisheye image (``nearest`` for depth)."""
        return cv2.remap(image, self.map_x, self.map_y, cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT)

    def render(self, renderer: Renderer, T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fisheye colour image ``uint8 (H, W, 3)`` and z-depth ``float32 (H, W)`` at ``T_world_cam``."""
        image, depth = renderer.render(T_world_cam, self.pinhole)
        return self.warp(image), self.warp(depth, nearest=True)

    def camera_yaml(self) -> str:
        """The vslam ``camera.yaml`` text of this lens (``model: equidistant``)."""
        K, (w, h) = self.K, self.size
        return (f"fx: {float(K[0, 0])!r}\nfy: {float(K[1, 1])!r}\ncx: {float(K[0, 2])!r}\ncy: {float(K[1, 2])!r}\nwidth: {w}\nheight: {h}\n"
                f"model: equidistant\ndist: [{', '.join(repr(float(d)) for d in self.D)}]\n")
