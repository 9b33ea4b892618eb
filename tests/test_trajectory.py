"""Trajectory file formats: round trips for TUM, KITTI (+times), EuRoC; bad inputs; detection."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vslam.errors import TrajectoryError
from vslam.trajectory import (
    Trajectory, detect_format, read_euroc, read_kitti, read_trajectory, read_tum, write_euroc,
    write_kitti, write_trajectory, write_tum,
)


def random_trajectory(n: int = 25, seed: int = 0, t0: float = 1305031102.160407) -> Trajectory:
    rng = np.random.default_rng(seed)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    T[:, :3, 3] = rng.normal(scale=3.0, size=(n, 3))
    ts = t0 + np.cumsum(rng.uniform(0.02, 0.05, n))
    return Trajectory(ts, T)


def assert_same(a: Trajectory, b: Trajectory, t_tol: float, pose_tol: float) -> None:
    assert len(a) == len(b)
    np.testing.assert_allclose(a.timestamps, b.timestamps, rtol=0, atol=t_tol)
    np.testing.assert_allclose(a.T_world_cam, b.T_world_cam, rtol=0, atol=pose_tol)


def test_tum_round_trip(tmp_path):
    traj = random_trajectory()
    write_tum(tmp_path / "t.txt", traj)
    back = read_tum(tmp_path / "t.txt")
    assert_same(traj, back, 1e-6, 1e-8)
    assert detect_format(tmp_path / "t.txt") == "tum"


def test_kitti_round_trip_with_and_without_times(tmp_path):
    traj = random_trajectory(t0=0.0)
    write_kitti(tmp_path / "k.txt", traj, tmp_path / "times.txt")
    back = read_kitti(tmp_path / "k.txt", tmp_path / "times.txt")
    assert_same(traj, back, 1e-6, 1e-8)
    assert detect_format(tmp_path / "k.txt") == "kitti"
    no_times = read_trajectory(tmp_path / "k.txt")
    np.testing.assert_array_equal(no_times.timestamps, np.arange(len(traj)))
    from_array = read_kitti(tmp_path / "k.txt", traj.timestamps + 5.0)
    np.testing.assert_allclose(from_array.timestamps, traj.timestamps + 5.0)


def test_euroc_round_trip(tmp_path):
    traj = random_trajectory(t0=1403715273.262142976)
    write_euroc(tmp_path / "e.csv", traj)
    back = read_euroc(tmp_path / "e.csv")
    assert_same(traj, back, 1e-6, 1e-8)  # ns integers; float64 seconds keep ~0.2 us here
    assert detect_format(tmp_path / "e.csv") == "euroc"


@pytest.mark.parametrize("fmt", ["tum", "kitti", "euroc"])
def test_write_read_trajectory_dispatch(tmp_path, fmt):
    traj = random_trajectory(t0=0.0 if fmt == "kitti" else 100.0)
    path = tmp_path / f"x.{fmt}"
    write_trajectory(path, traj, fmt, times_path=tmp_path / "times.txt" if fmt == "kitti" else None)
    back = read_trajectory(path, times=tmp_path / "times.txt" if fmt == "kitti" else None)
    assert_same(traj, back, 1e-6, 1e-8)


def test_euroc_column_order_and_extra_columns(tmp_path):
    # 90 deg about z: q (w, x, y, z) = (cos 45, 0, 0, sin 45); velocity/bias columns are ignored.
    c = np.sqrt(0.5)
    (tmp_path / "gt.csv").write_text(
        "#timestamp,p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z [],v_x\n"
        f"1000000000,1.0,2.0,3.0,{c},0,0,{c},9.0\n"
        f"1500000000,1.5,2.0,3.0,1,0,0,0,9.0\n"
    )
    traj = read_euroc(tmp_path / "gt.csv")
    np.testing.assert_allclose(traj.timestamps, [1.0, 1.5])
    np.testing.assert_allclose(traj.T_world_cam[0, :3, 3], [1, 2, 3])
    np.testing.assert_allclose(traj.T_world_cam[0, :3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)


def test_real_files_read(shared_data):
    d = shared_data / "trajectories"
    gt = read_trajectory(d / "tum/freiburg1_xyz-groundtruth.txt")
    assert len(gt) == 3000
    k = read_trajectory(d / "kitti/KITTI_00_gt.txt", times=d / "kitti/KITTI_00_gt_times.txt")
    assert len(k) == 4541 and k.timestamps[1] == pytest.approx(0.1037359)
    e = read_trajectory(d / "euroc/V102_groundtruth.csv")
    assert len(e) == 16702
    R = e.T_world_cam[:, :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)


BAD = {
    "empty": ("# only a comment\n\n", "empty"),
    "malformed": ("1.0 0 0 0 0 0 0 1\n2.0 0 0 zero 0 0 0 1\n", ":2: not a number"),
    "short_line": ("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n", ":2: TUM trajectory line has 7 numbers"),
    "unsorted": ("2.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n", ":2: timestamps are not sorted"),
    "duplicate": ("# c\n1.0 0 0 0 0 0 0 1\n1.0 0 0 1 0 0 0 1\n", ":3: duplicate timestamp"),
    "nan": ("1.0 0 0 nan 0 0 0 1\n", "NaN or inf"),
    "zero_quat": ("1.0 0 0 0 0 0 0 0\n", "zero quaternion"),
    "kitti_as_tum": (" ".join(["1"] * 12) + "\n", "looks like a KITTI file"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_tum_files_raise_naming_file(tmp_path, case):
    text, needle = BAD[case]
    path = tmp_path / f"{case}.txt"
    path.write_text(text)
    with pytest.raises(TrajectoryError) as exc:
        read_tum(path)
    assert str(path) in str(exc.value) and needle in str(exc.value)


def test_missing_file_and_unknown_format(tmp_path):
    with pytest.raises(TrajectoryError, match="not found"):
        read_trajectory(tmp_path / "nope.txt")
    with pytest.raises(TrajectoryError, match="not found"):
        read_tum(tmp_path / "nope.txt")
    (tmp_path / "a.txt").write_text("1 0 0 0 0 0 0 1\n")
    with pytest.raises(TrajectoryError, match="unknown trajectory format 'ply'"):
        read_trajectory(tmp_path / "a.txt", "ply")


def test_duplicates_keep_last(tmp_path):
    path = tmp_path / "d.txt"
    path.write_text("1.0 0 0 0 0 0 0 1\n1.0 5 0 0 0 0 0 1\n2.0 7 0 0 0 0 0 1\n")
    traj = read_tum(path, duplicates="keep_last")
    np.testing.assert_array_equal(traj.timestamps, [1.0, 2.0])
    np.testing.assert_array_equal(traj.positions[:, 0], [5.0, 7.0])


def test_kitti_bad_inputs(tmp_path):
    path = tmp_path / "k.txt"
    path.write_text(" ".join(["0"] * 12) + "\n" + " ".join(["0"] * 12) + "\n")
    with pytest.raises(TrajectoryError, match="2 poses but only 1 timestamps"):
        read_kitti(path, np.array([0.0]))
    (tmp_path / "times.txt").write_text("0.0\n0.0\n")
    with pytest.raises(TrajectoryError, match=r"times.txt:2: duplicate timestamp"):
        read_kitti(path, tmp_path / "times.txt")
    (tmp_path / "tum.txt").write_text("1 0 0 0 0 0 0 1\n")
    with pytest.raises(TrajectoryError, match="looks like a TUM file"):
        read_kitti(tmp_path / "tum.txt")


def test_trajectory_shape_checks():
    with pytest.raises(TrajectoryError, match="2 timestamps but 1 poses"):
        Trajectory(np.array([0.0, 1.0]), np.eye(4)[None])
    with pytest.raises(TrajectoryError, match=r"\(N, 4, 4\)"):
        Trajectory(np.array([0.0]), np.zeros((1, 3, 4)))


def test_write_to_missing_folder(tmp_path):
    with pytest.raises(TrajectoryError, match="does not exist"):
        write_tum(tmp_path / "no" / "t.txt", random_trajectory(3))
