"""Loops of sparse, texture-poor RGB-D keyframe sequences: the candidate keyframes' keypoints with
depth matched keyframe by keyframe (verification), the covisibility-confirmed single detection
(closing), and the real loop of TUM fr3/cabinet (58 keyframes)."""
from __future__ import annotations

import numpy as np

from vslam.geometry.camera import PinholeCamera
from vslam.loop.verification import Features, verify
from vslam.map.mappoint import MapPointStore


def _scene(seed: int = 0):
    """60 points in front of a camera at the origin of the candidate's world, seen by the query from
    ``T_world_q`` (0.3 m, ~5 deg away); the candidate side holds every point twice (two keyframes
    seeing the same scene: identical descriptors up to 3 flipped bits)."""
    rng = np.random.default_rng(seed)
    camera = PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
    X_world = np.column_stack([rng.uniform(-1.0, 1.0, 60), rng.uniform(-0.8, 0.8, 60), rng.uniform(2.0, 4.0, 60)])
    a = np.radians(5.0)
    T_world_q = np.eye(4)
    T_world_q[:3, :3] = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    T_world_q[:3, 3] = [0.3, 0.0, 0.05]
    T_q_world = np.linalg.inv(T_world_q)
    X_q = X_world @ T_q_world[:3, :3].T + T_q_world[:3, 3]
    uv = X_q[:, :2] / X_q[:, 2:] * 500.0 + [320.0, 240.0]
    desc = rng.integers(0, 256, (60, 32), dtype=np.uint8)

    def noisy() -> np.ndarray:
        d = desc.copy()
        bits = rng.integers(0, 256, (60, 3))
        rows = np.repeat(np.arange(60), 3)
        d[rows, bits.ravel() // 8] ^= (1 << (bits.ravel() % 8)).astype(np.uint8)
        return d

    feat = Features(uv, noisy(), np.zeros(60, np.int64), X_q[:, 2].copy(), None, X_q)
    store = MapPointStore()
    store.add(np.array([[0.0, 0.0, 50.0], [1.0, 0.0, 50.0]]), rng.integers(0, 256, (2, 32), dtype=np.uint8),
              np.zeros(3), 0)
    extra_X = np.concatenate([X_world, X_world])
    extra_desc = np.concatenate([noisy(), noisy()])
    extra_src = np.repeat([3, 4], 60)
    return camera, feat, store, extra_X, extra_desc, extra_src, T_world_q


def test_keypoints_with_depth_matched_keyframe_by_keyframe():
    camera, feat, store, extra_X, extra_desc, extra_src, T_world_q = _scene()
    no_pts = np.zeros(0, np.int64)
    # pooled: every point has a near-identical twin from the other keyframe, so the ratio test
    # rejects them all and nothing is left to verify
    pooled = verify(feat, store, no_pts, camera, "rgbd", extra_X=extra_X, extra_desc=extra_desc)
    assert pooled is None
    ver = verify(feat, store, no_pts, camera, "rgbd", extra_X=extra_X, extra_desc=extra_desc, extra_src=extra_src)
    assert ver is not None
    assert ver.n_ransac == 120  # each query keypoint agrees with both keyframes
    assert ver.n_inliers == 0  # no map point: nothing to fuse
    np.testing.assert_allclose(ver.T_world_cam, T_world_q, atol=1e-6)


def test_per_keyframe_matches_cached_across_groups(monkeypatch):
    """``extra_matches``: a query verified against overlapping candidate groups matches each
    keyframe's depth keypoints once; the cached pairs give the same verification."""
    import vslam.loop.verification as verification

    camera, feat, store, extra_X, extra_desc, extra_src, T_world_q = _scene()
    no_pts = np.zeros(0, np.int64)
    calls = []
    match = verification.match_descriptors
    monkeypatch.setattr(verification, "match_descriptors", lambda *a, **k: calls.append(len(a[1])) or match(*a, **k))
    kw = dict(extra_X=extra_X, extra_desc=extra_desc, extra_src=extra_src)
    plain = verify(feat, store, no_pts, camera, "rgbd", **kw)
    assert calls == [60, 60]
    cache: dict = {}
    first = verify(feat, store, no_pts, camera, "rgbd", extra_matches=cache, **kw)
    assert sorted(cache) == [3, 4] and len(calls) == 4
    # a second group holding keyframe 4 (rows in another order) and a new keyframe 5: only 5 is matched
    sel = np.flatnonzero(extra_src == 4)
    X2 = np.concatenate([extra_X[:60], extra_X[sel]])
    D2 = np.concatenate([extra_desc[:60], extra_desc[sel]])
    S2 = np.repeat([5, 4], 60)
    again = verify(feat, store, no_pts, camera, "rgbd", extra_X=X2, extra_desc=D2, extra_src=S2, extra_matches=cache)
    fresh = verify(feat, store, no_pts, camera, "rgbd", extra_X=X2, extra_desc=D2, extra_src=S2)
    assert len(calls) == 4 + 1 + 2 and sorted(cache) == [3, 4, 5]
    for a, b in [(plain, first), (fresh, again)]:
        assert a.n_ransac == b.n_ransac == 120
        np.testing.assert_array_equal(a.T_world_cam, b.T_world_cam)
    np.testing.assert_allclose(again.T_world_cam, T_world_q, atol=1e-6)


def test_ransac_pose_refined_on_reprojection():
    """The 3D-3D RANSAC fits noisy depth (RGB-D noise grows with z^2) as if it were exact; with
    ``refine_ransac`` its inliers' reprojection errors (exact pixels here) refine the pose, which is
    what the guided matching starts from and what a loop without map-point inliers gets."""
    camera, feat, store, extra_X, extra_desc, extra_src, T_world_q = _scene()
    rng = np.random.default_rng(1)
    z = feat.X_cam[:, 2] * (1.0 + rng.normal(0.0, 0.02, len(feat.X_cam)) * feat.X_cam[:, 2])
    noisy = Features(feat.uv_undist, feat.descriptors, feat.octave, z, None, feat.X_cam * (z / feat.X_cam[:, 2])[:, None])
    no_pts = np.zeros(0, np.int64)
    kw = dict(extra_X=extra_X, extra_desc=extra_desc, extra_src=extra_src)

    def error(ver) -> tuple[float, float]:
        D = np.linalg.inv(T_world_q) @ ver.T_world_cam
        return float(np.linalg.norm(D[:3, 3])), float(np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1))))

    plain = verify(noisy, store, no_pts, camera, "rgbd", **kw)
    refined = verify(noisy, store, no_pts, camera, "rgbd", refine_ransac=True, **kw)
    assert plain.n_ransac == refined.n_ransac >= 100 and refined.n_inliers == 0
    t_plain, r_plain = error(plain)
    t_ref, r_ref = error(refined)
    assert t_plain > 0.02 and r_plain > 0.3, (t_plain, r_plain)  # measured 0.057 m / 0.94 deg
    assert t_ref < 1e-4 and r_ref < 1e-3, (t_ref, r_ref)
    # pairs consistent in 3D (within the RANSAC threshold) but not in the image: rejected
    shuffled = Features(feat.uv_undist[::-1].copy(), feat.descriptors, feat.octave, feat.depth, None, feat.X_cam)
    assert verify(shuffled, store, no_pts, camera, "rgbd", **kw) is not None
    assert verify(shuffled, store, no_pts, camera, "rgbd", refine_ransac=True, **kw) is None


def test_cabinet_loop_closes(shared_data, cabinet_run_integer_corners):
    """TUM fr3/cabinet, 58 keyframes around a texture-poor cabinet: keyframe 56 is 0.28 m / 3.4 deg
    from keyframe 0, but only ~15-25 keypoints match across the loop (most of the map's points
    were culled) and only three keyframes come back, so neither ``min_inliers`` nor temporal
    consistency can accept it; the covisibility-confirmed single detection does."""
    from vslam.trajectory import read_tum

    root = shared_data / "tum_fr3_cabinet_keyframes58"
    # the default pipeline with integer FAST corners (tests/conftest.py): with the sub-pixel keypoints of
    # the default (issue 24) the keyframes' places verify below this loop's threshold and no loop closes
    _, system, _ = cabinet_run_integer_corners
    loops = system.stats()["loops"]
    assert len(loops) == 1, system.stats()["loop_closing"]
    query, match, inliers = loops[0]
    # 15 inliers before the tracker's dense RGB-D refinement / dense links (session 3); 11 since:
    # a different map (more keyframes), the same loop; 10 with the disparity residual (RANSAC pose
    # refined on reprojection before the guided matching: 0 without)
    # pinned: exactly 10 (counting the unrefined RANSAC matches as inliers would give 17)
    assert [query, match, inliers] == [57, 2, 10]
    # the loop's end is pulled onto the start: the last keyframe's error relative to keyframe 0
    gt = read_tum(root / "groundtruth.txt")
    kfs = sorted(system.map.keyframes.values(), key=lambda k: k.id)
    first, last = kfs[0], kfs[-1]
    T_est = np.linalg.inv(first.T_world_cam) @ last.T_world_cam
    T_gt = np.linalg.inv(gt.T_world_cam[first.frame_index]) @ gt.T_world_cam[last.frame_index]
    assert np.linalg.norm(T_est[:3, 3] - T_gt[:3, 3]) < 0.08  # 0.50 m without the loop, 0.02 m with it
    # a loop this weak (confirmed, < min_inliers) keeps the essential graph's correction: the global BA
    # re-opened it (ATE 0.0496 m; loop closing off 0.0268)
    from vslam.eval.evaluate import evaluate_trajectories

    assert system.stats()["backend"].get("global_ba_calls", 0) == 0
    assert 0.0318 <= evaluate_trajectories(system.trajectory(), gt).ate.rmse <= 0.0327  # measured 0.032233
