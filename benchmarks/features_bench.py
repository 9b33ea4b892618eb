"""Time per call of the feature layer: ORB detection, descriptor matching, guided matching, KLT;
with OpenCV's own ORB / BFMatcher as references on the same inputs.

Run ``python benchmarks/features_bench.py`` (prints a table) or call :func:`run_features_bench`
(returns ``{name: {"ms_median": .., "ms_min": .., "cpu_ms_median": .., "n": ..}}``).
Inputs are the real KITTI 06 frames 0/1 (1226x370, stereo) and a TUM fr1/desk frame (640x480)
from the shared data folder; without it, scikit-image textures of the same sizes.
Timings are wall-clock medians over ``repeats`` calls, plus the median CPU time of this process
(what to compare on a shared, loaded machine). OpenCV threads are set to 1 unless given.
"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from vslam.features import (
    FeatureConfig,
    KLTConfig,
    MatcherConfig,
    create_detector,
    detect_new_points,
    match_by_projection,
    match_descriptors,
    track_klt,
)


def _time(fn: Callable[[], object], repeats: int) -> tuple[float, float, float]:
    """Median and best wall time and median process CPU time (ms)."""
    fn()  # warm-up (imports, OpenCV / faiss initialisation)
    ts, cs = [], []
    for _ in range(repeats):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
        cs.append(time.process_time() - c0)
    return 1e3 * float(np.median(ts)), 1e3 * float(np.min(ts)), 1e3 * float(np.median(cs))


def _images(data: Path | None) -> dict[str, np.ndarray]:
    """KITTI left/right frame 0, left frame 1, a TUM 640x480 frame (or textures of those sizes)."""
    if data is not None:
        kitti = data / "kitti_odometry/sequences/06"
        tum = data / "tum_rgbd_freiburg1_desk_9frames/rgb"
        if kitti.is_dir() and tum.is_dir():
            read = lambda p: cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)  # noqa: E731
            return {
                "kitti_l0": read(kitti / "image_0/000000.png"),
                "kitti_r0": read(kitti / "image_1/000000.png"),
                "kitti_l1": read(kitti / "image_0/000001.png"),
                "tum": read(sorted(tum.iterdir())[0]),
            }
    import skimage.data

    from scipy.ndimage import shift as nd_shift

    tex = np.tile(skimage.data.gravel(), (1, 3))[:370, :1226]
    return {
        "kitti_l0": tex,
        "kitti_r0": nd_shift(tex.astype(float), (0, -15.0), mode="wrap").astype(np.uint8),
        "kitti_l1": nd_shift(tex.astype(float), (1.0, 2.0), mode="wrap").astype(np.uint8),
        "tum": cv2.resize(skimage.data.astronaut()[..., 1], (640, 480)),
    }


def run_features_bench(repeats: int = 10, data: Path | None = None, cv_threads: int = 1) -> dict:
    """Time the feature layer; see the module docstring for the returned dict."""
    if data is None:
        env = os.environ.get("VSLAM_SHARED_DATA")
        data = Path(env) if env else Path(__file__).resolve().parents[1].parent / "shared" / "data"
    cv2.setNumThreads(cv_threads)
    img = _images(data if data.is_dir() else None)
    out: dict[str, dict] = {}

    def add(name: str, fn: Callable[[], object], n: int) -> None:
        med, best, cpu = _time(fn, repeats)
        out[name] = {"ms_median": med, "ms_min": best, "cpu_ms_median": cpu, "n": n}

    orb = create_detector(FeatureConfig(detector="orb", n_features=2000))
    cv_orb = cv2.ORB_create(nfeatures=2000)
    for key, label in (("tum", "640x480"), ("kitti_l0", "1226x370")):
        g = img[key]
        add(f"orb_grid_detect_2000_{label}", lambda g=g: orb.detect(g), len(orb.detect(g)))
        add(f"opencv_orb_detectAndCompute_2000_{label} (reference)",
            lambda g=g: cv_orb.detectAndCompute(g, None), 2000)
    for name in ("gftt_orb", "sift", "akaze", "brisk"):
        det = create_detector(FeatureConfig(detector=name, n_features=2000))
        add(f"{name}_detect_1226x370", lambda det=det: det.detect(img["kitti_l0"]), len(det.detect(img["kitti_l0"])))

    f0 = orb.detect(img["kitti_l0"])
    f1 = orb.detect(img["kitti_l1"])
    fr = orb.detect(img["kitti_r0"])
    d0, d1 = f0.descriptors, f1.descriptors
    cfg = MatcherConfig()
    add(f"match_faiss_{len(d0)}x{len(d1)}_ratio_mutual",
        lambda: match_descriptors(d0, d1, True, config=cfg), len(match_descriptors(d0, d1, True, config=cfg)[0]))
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    add(f"opencv_bf_knn2+knn1_{len(d0)}x{len(d1)} (reference)",
        lambda: (bf.knnMatch(d0, d1, k=2), bf.knnMatch(d1, d0, k=1)), len(d0))

    # guided matching: the frame-0 keypoints "projected" through the frame-1 matches
    i0, i1, _ = match_descriptors(d0, d1, True)
    rng = np.random.default_rng(0)
    proj = f0.uv.astype(np.float64) + rng.normal(0, 1.0, f0.uv.shape)
    proj[i0] = f1.uv[i1] + rng.normal(0, 1.0, (len(i1), 2))
    radius = 15.0 * 1.2 ** f0.octave
    add(f"match_by_projection_{len(f0)}x{len(f1)}_r15",
        lambda: match_by_projection(proj, d0, f1.uv, d1, radius, True, max_distance=100), len(f0))

    pts = cv2.goodFeaturesToTrack(img["kitti_l0"], 1000, 0.001, 10).reshape(-1, 2)
    kcfg = KLTConfig()
    add(f"klt_fb_{len(pts)}pts_1226x370", lambda: track_klt(img["kitti_l0"], img["kitti_l1"], pts, kcfg), len(pts))
    add("detect_new_points_gftt_to_1500", lambda: detect_new_points(img["kitti_l1"], pts[:500], 1500), 1000)

    return out


def main() -> int:
    repeats = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    res = run_features_bench(repeats)
    width = max(len(k) for k in res)
    sys.stdout.write(f"{'benchmark':<{width}}  {'median ms':>9}  {'min ms':>8}  {'cpu ms':>8}  {'n':>6}\n")
    for name, r in res.items():
        sys.stdout.write(f"{name:<{width}}  {r['ms_median']:9.2f}  {r['ms_min']:8.2f}  "
                         f"{r['cpu_ms_median']:8.2f}  {r['n']:6d}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
