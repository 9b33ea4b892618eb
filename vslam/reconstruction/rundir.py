"""Dense reconstruction of a ``vslam run`` output folder: reopen its sequence, fuse its keyframes.

The run folder holds ``stats.json`` (``path``, ``sensor``, ``dataset``, ``start_frame``),
``keyframes.txt`` and ``trajectory.txt`` (TUM format, ``T_world_cam``). The frames whose timestamps
appear in the chosen trajectory are read again from the dataset and fused with
:class:`~vslam.reconstruction.dense.TSDFFusion` along the *estimated* poses.
"""
from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np

from vslam.errors import VslamError
from vslam.textfile import open_text
from vslam.reconstruction.dense import TSDFConfig, TSDFFusion
from vslam.reconstruction.stereo_depth import StereoDepthConfig, default_max_depth

log = logging.getLogger(__name__)

TIME_TOLERANCE_S = 1e-3  # TUM files store 6 decimals; dataset frames are >= 1/200 s apart
RGBD_DEPTH_MAX = 4.0  # metres: structured-light / ToF depth is noisy beyond this
STEREO_VOXELS_PER_RANGE = 400  # auto stereo voxel = depth_max / 400 (KITTI: ~0.12 m, EuRoC: ~0.016 m)


def _read_stats(run_dir: Path) -> dict:
    path = run_dir / "stats.json"
    if not path.is_file():
        raise VslamError(f"{run_dir}: no stats.json; pass a folder written by `vslam run`")
    try:
        stats = json.loads(open_text(path, VslamError).read())
    except json.JSONDecodeError as exc:
        raise VslamError(f"{path}: not valid JSON ({exc})") from None
    for key in ("path", "sensor"):
        if not stats.get(key):
            raise VslamError(f"{path}: has no '{key}'; it was not written by `vslam run`")
    return stats


def select_frames(dataset_timestamps: np.ndarray, pose_timestamps: np.ndarray,
                  tolerance: float = TIME_TOLERANCE_S) -> tuple[np.ndarray, np.ndarray]:
    """``(dataset indices, pose indices)`` of the poses whose timestamp matches a frame's within ``tolerance``."""
    ts = np.asarray(dataset_timestamps, dtype=np.float64)
    q = np.asarray(pose_timestamps, dtype=np.float64)
    if len(ts) == 0 or len(q) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    order = np.argsort(ts)
    sorted_ts = ts[order]
    j = np.clip(np.searchsorted(sorted_ts, q), 1, len(ts) - 1) if len(ts) > 1 else np.zeros(len(q), int)
    if len(ts) > 1:
        left_closer = np.abs(sorted_ts[j - 1] - q) <= np.abs(sorted_ts[j] - q)
        j = np.where(left_closer, j - 1, j)
    ok = np.abs(sorted_ts[j] - q) <= tolerance
    return order[j[ok]], np.flatnonzero(ok)


def reconstruct_run(
    run_dir: str | Path,
    voxel_size: float | None = None,
    every: int | None = None,
    depth_max: float | None = None,
    sdf_trunc: float | None = None,
    max_frames: int | None = None,
    output_dir: str | Path | None = None,
    stereo: StereoDepthConfig | None = None,
    progress=None,
) -> dict:
    """Fuse a run's keyframes (or every ``every``-th tracked frame) into ``mesh.ply`` and ``dense.ply``.

    Args:
        run_dir: a ``vslam run`` output folder.
        voxel_size: metres; None = 0.01 for RGB-D, ``depth_max / 400`` for stereo.
        every: use every N-th pose of ``trajectory.txt`` instead of ``keyframes.txt``.
        depth_max: metres; None = 4 for RGB-D, the depth of an 8-pixel disparity for stereo.
        sdf_trunc: metres; None = 4 voxels.
        max_frames: fuse at most this many frames, evenly spaced over the selection.
        output_dir: where to write the PLY files (default ``run_dir``).
        progress: a tqdm-like factory (``progress(iterable, total=, desc=)``) to show the fusion's
            progress with, e.g. ``functools.partial(tqdm, file=sys.stderr)``; None shows nothing.

    Returns:
        counts (``frames_fused``, ``vertices``, ``triangles``, ``points``), ``mesh`` and ``dense``
        paths (str), the settings used and timings.
    """
    from vslam.datasets import KINDS, open_dataset

    run_dir = Path(run_dir)
    stats = _read_stats(run_dir)
    sensor = stats["sensor"]
    if sensor not in ("rgbd", "stereo"):
        raise VslamError(f"{run_dir}: the run used sensor '{sensor}'; dense reconstruction needs metric depth "
                         "from an rgbd or stereo run")
    kind = stats.get("dataset") if stats.get("dataset") in KINDS else None
    seq_path = stats["path"]
    if not Path(seq_path).exists():
        raise VslamError(f"{run_dir}/stats.json names the sequence {seq_path!r}, which is not available here")
    ds = open_dataset(seq_path, kind=kind, sensor=sensor)

    traj, frame_idx, pose_idx, source = _poses_to_fuse(run_dir, ds, seq_path, every, max_frames)

    if depth_max is None:
        depth_max = RGBD_DEPTH_MAX if sensor == "rgbd" else default_max_depth(ds.camera)
    if voxel_size is None:
        voxel_size = 0.01 if sensor == "rgbd" else max(0.01, depth_max / STEREO_VOXELS_PER_RANGE)
    config = TSDFConfig(voxel_size=voxel_size, sdf_trunc=sdf_trunc, depth_max=depth_max,
                        depth_source="depth" if sensor == "rgbd" else "stereo",
                        stereo=stereo if stereo is not None else StereoDepthConfig())
    log.info("fusing %d frames of %s (%s, voxel %.3f m, depth <= %.1f m)", len(frame_idx), seq_path, source,
             voxel_size, depth_max)
    t0 = time.perf_counter()
    fusion = TSDFFusion(config)
    pairs = list(zip(frame_idx, pose_idx))
    for i, k in (progress(pairs, total=len(pairs), desc="TSDF fusion", unit="frame") if progress else pairs):
        fusion.integrate_frame(ds[int(i)], traj.T_world_cam[k])
    result = fusion.extract()
    paths = result.save(Path(output_dir) if output_dir is not None else run_dir)
    out = result.summary()
    out.update({
        "mesh": str(paths["mesh"]), "dense": str(paths["dense"]), "poses_from": source,
        "voxel_size": float(voxel_size), "sdf_trunc": config.truncation, "depth_max": float(depth_max),
        "sensor": sensor, "total_s": round(time.perf_counter() - t0, 3),
    })
    return out



def _poses_to_fuse(run_dir: Path, ds, seq_path: str, every: int | None, max_frames: int | None):
    """The poses to fuse (``keyframes.txt``, or every ``every``-th pose of ``trajectory.txt``) and
    the dataset frames they belong to: ``(trajectory, frame indices, pose indices, where from)``."""
    from vslam.trajectory import read_tum

    kf_file, traj_file = run_dir / "keyframes.txt", run_dir / "trajectory.txt"
    use_kf = every is None and kf_file.is_file() and kf_file.stat().st_size > 0
    if every is not None and every < 1:
        raise VslamError(f"--every must be >= 1, got {every}")
    if use_kf:
        traj, source = read_tum(kf_file), kf_file.name
    else:
        if not traj_file.is_file():
            raise VslamError(f"{run_dir}: neither keyframes.txt nor trajectory.txt; run `vslam run` again")
        step = every if every is not None else 10
        if every is None:
            log.warning("%s: no keyframes.txt, using every %d-th pose of trajectory.txt", run_dir, step)
        full = read_tum(traj_file)
        traj = full.subset(np.arange(0, len(full), step))
        source = f"{traj_file.name} every {step}"
    frame_idx, pose_idx = select_frames(ds.timestamps, traj.timestamps)
    if len(frame_idx) == 0:
        raise VslamError(f"{run_dir}: no timestamp of {source} matches a frame of {seq_path}; "
                         "was the run made on this sequence?")
    if len(frame_idx) < len(traj):
        log.warning("%d of %d poses of %s have no matching frame", len(traj) - len(frame_idx), len(traj), source)
    if max_frames is not None and len(frame_idx) > max_frames:
        keep = np.unique(np.round(np.linspace(0, len(frame_idx) - 1, max(max_frames, 1))).astype(int))
        frame_idx, pose_idx = frame_idx[keep], pose_idx[keep]
    return traj, frame_idx, pose_idx, source


__all__ = ["reconstruct_run", "select_frames"]
