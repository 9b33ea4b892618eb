"""Sub-pixel keypoint refinement (issue #24 item 3, ``features.subpixel``; ``auto``: parabola for stereo and
RGB-D, off for monocular)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from vslam.errors import ConfigError
from vslam.features.config import FeatureConfig
from vslam.features.detect import create_detector, subpixel_peaks

SUPERSAMPLE = 16


def _corner(cx: float, cy: float, size: int = 40, angle: float = 0.3) -> np.ndarray:
    """A blurred 90-degree corner (apex at pixel-centre coordinates ``cx, cy``), rendered by
    supersampling, so moving it by a fraction of a pixel changes the image as a camera would."""
    yy, xx = np.mgrid[0:size * SUPERSAMPLE, 0:size * SUPERSAMPLE]
    xx, yy = (xx + 0.5) / SUPERSAMPLE - 0.5, (yy + 0.5) / SUPERSAMPLE - 0.5
    xr = np.cos(angle) * (xx - cx) + np.sin(angle) * (yy - cy)
    yr = -np.sin(angle) * (xx - cx) + np.cos(angle) * (yy - cy)
    big = ((xr > 0) & (yr > 0)) * 180.0 + 40.0
    small = big.reshape(size, SUPERSAMPLE, size, SUPERSAMPLE).mean(axis=(1, 3))
    return cv2.GaussianBlur(small, (0, 0), 1.0).astype(np.uint8)


def test_refined_corners_follow_subpixel_shifts():
    """The corner moved by 40 random sub-pixel shifts: the integer response peak (as FAST gives
    integer corners) minus the shift scatters with its quantization, std 0.27 / 0.28 px (x / y,
    measured); the refined peak by 0.11 / 0.13 px (a constant bias towards the inside of the corner,
    the same in every image, does not count). Band: below 0.6 times the integer scatter on both axes."""
    rng = np.random.default_rng(0)
    err_int, err_ref = [], []
    for _ in range(40):
        s = rng.uniform(-0.5, 0.5, 2)
        img = _corner(20 + s[0], 20 + s[1])
        R = cv2.cornerMinEigenVal(img, 3)[15:26, 15:26]
        y0, x0 = np.unravel_index(int(np.argmax(R)), R.shape)
        x0, y0 = np.array([x0 + 15]), np.array([y0 + 15])
        xf, yf = subpixel_peaks(img, x0, y0)
        err_int.append([x0[0] - s[0], y0[0] - s[1]])
        err_ref.append([xf[0] - s[0], yf[0] - s[1]])
    std_int, std_ref = np.std(err_int, axis=0), np.std(err_ref, axis=0)
    assert np.all(std_ref < 0.6 * std_int), (std_ref, std_int)
    assert np.all(np.abs(np.subtract(err_ref, err_int)) <= 0.5 + 1e-12)  # at most half a pixel per axis


@pytest.mark.parametrize("mode", ["cornersubpix", "parabola"])
def test_refinement_moves_keypoints_by_at_most_half_a_level_pixel(mode):
    """Same keypoints and descriptors as without refinement; each moves by at most half a pixel of
    its level (0.5 * 1.2^octave at level 0; a level's size is rounded, so its scale is within 1 %)."""
    rng = np.random.default_rng(1)
    img = cv2.resize(cv2.GaussianBlur((rng.random((120, 160)) * 255).astype(np.float32), (0, 0), 1.0), (640, 480),
                     interpolation=cv2.INTER_CUBIC)
    img = np.clip(img, 0, 255).astype(np.uint8)
    a = create_detector(FeatureConfig()).detect(img)
    b = create_detector(FeatureConfig(subpixel=mode)).detect(img)
    assert np.array_equal(a.descriptors, b.descriptors) and np.array_equal(a.octave, b.octave)
    shift = np.abs(b.uv.astype(np.float64) - a.uv).max(axis=1)
    assert np.all(shift <= 0.5 * 1.2 ** a.octave * 1.01 + 1e-3)  # level sizes are rounded: 1 %
    if mode == "parabola":
        assert np.mean(shift > 0) > 0.5  # most corners do move


@pytest.mark.parametrize("sensor, mode", [("mono", "off"), ("mono-inertial", "off"), ("stereo", "parabola"),
                                          ("stereo-inertial", "off"), ("rgbd", "parabola"), ("rgbd-inertial", "off")])
def test_auto_is_parabola_for_stereo_and_rgbd_and_off_for_the_others(sensor, mode):
    assert FeatureConfig().subpixel == "auto"
    assert FeatureConfig().for_sensor(sensor).subpixel == mode
    assert FeatureConfig(subpixel="cornersubpix").for_sensor(sensor).subpixel == "cornersubpix"  # a choice stays


def test_an_unresolved_auto_refines_nothing():
    rng = np.random.default_rng(2)
    img = (rng.random((240, 320)) * 255).astype(np.uint8)
    a = create_detector(FeatureConfig(subpixel="auto")).detect(img)
    b = create_detector(FeatureConfig(subpixel="off")).detect(img)
    assert np.array_equal(a.uv, b.uv)


def test_the_system_resolves_auto_for_its_sensor():
    from vslam.geometry.camera import PinholeCamera
    from vslam.config import Config
    from vslam.system import System

    cam = PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
    assert System(Config(), cam, sensor="rgbd").feature_config.subpixel == "parabola"
    assert System(Config(), cam, sensor="mono").feature_config.subpixel == "off"


def test_unknown_subpixel_mode_is_refused():
    with pytest.raises(ConfigError):
        FeatureConfig(subpixel="lanczos")


def test_octave_range_limits_which_levels_are_refined():
    """``subpixel_min_octave`` / ``subpixel_max_octave``: keypoints of the other levels keep the
    integer-corner positions of an unrefined run, bit for bit."""
    rng = np.random.default_rng(2)
    img = cv2.resize(cv2.GaussianBlur((rng.random((120, 160)) * 255).astype(np.float32), (0, 0), 1.0), (640, 480),
                     interpolation=cv2.INTER_CUBIC)
    img = np.clip(img, 0, 255).astype(np.uint8)
    plain = create_detector(FeatureConfig()).detect(img)
    for lo, hi in ((0, 0), (1, 31)):
        f = create_detector(FeatureConfig(subpixel="parabola", subpixel_min_octave=lo, subpixel_max_octave=hi)).detect(img)
        inside = (f.octave >= lo) & (f.octave <= hi)
        assert np.array_equal(f.uv[~inside], plain.uv[~inside])
        assert np.any(f.uv[inside] != plain.uv[inside])


def test_an_unquoted_off_in_yaml_means_off(tmp_path):
    """YAML 1.1 reads ``subpixel: off`` as the boolean False (run folders written while the setting
    was a boolean hold ``subpixel: false``): both mean ``off``; anything else unknown is refused."""
    import pytest

    from vslam.config import Config, load_config
    from vslam.errors import ConfigError

    for text in ("off", "false", "False"):
        p = tmp_path / f"{text}.yaml"
        p.write_text(f"features:\n  subpixel: {text}\n")
        assert load_config(Config, p).features.subpixel == "off"
    p = tmp_path / "on.yaml"
    p.write_text("features:\n  subpixel: on\n")
    with pytest.raises(ConfigError, match="subpixel"):
        load_config(Config, p)
