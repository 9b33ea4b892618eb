"""``vslam run PATH``: track a sequence and write trajectory, keyframes, stats and config."""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

from vslam.cli.common import add_gt_argument, ate_line, compile_notice

#: ``vslam.inertial.sensors.ALL_SENSORS``, spelled out: importing it would load numpy / OpenCV before
#: every ``vslam`` command (tests/cli/test_run_imu.py checks they agree)
ALL_SENSORS = ("mono", "stereo", "rgbd", "mono-inertial", "stereo-inertial", "rgbd-inertial")

log = logging.getLogger(__name__)


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "run", help="run SLAM on a sequence",
        description="Run SLAM on a sequence (TUM, KITTI, EuRoC, 7-Scenes, image folder, video or ROS 1/2 bag) "
                    "or live on a camera (camera:0) or stream (rtsp://..., http://...; needs --camera, "
                    "runs until the stream ends or Ctrl-C, which still writes every output).",
    )
    p.add_argument("path", help="sequence folder, video file, ROS bag (.bag file or ROS 2 bag folder), "
                                "or live: camera:N, rtsp://..., http://...")
    p.add_argument("--output", "-o", required=True, help="output folder")
    p.add_argument("--sensor", choices=list(ALL_SENSORS),
                   help="default: rgbd, else stereo, else mono; *-inertial: the same with the IMU (EuRoC imu0/ or "
                        "--imu), in a gravity-aligned (z up), metric world")
    p.add_argument("--imu", metavar="FILE",
                   help="IMU samples for an inertial sensor on a sequence without them (EuRoC CSV columns: "
                        "t, w_xyz rad/s, a_xyz m/s^2), its calibration (Kalibr camchain-imucam.yaml, imu.yaml, or "
                        "ORB-SLAM3 settings) beside it")
    p.add_argument("--dataset", help="force the format: tum, kitti, euroc, 7scenes, folder, video, rosbag")
    p.add_argument("--camera", metavar="FILE",
                   help="camera calibration overriding the sequence's: vslam camera.yaml, OpenCV YAML/XML, "
                        "ORB-SLAM2/3 settings, Kalibr camchain, ROS camera_info, KITTI calib.txt (detected), "
                        "or a TUM preset fr1|fr2|fr3")
    p.add_argument("--topics", metavar="COLOR[,DEPTH|,RIGHT][,IMU]",
                   help="image (and sensor_msgs/Imu) topics of a ROS bag (default: detected when unambiguous)")
    p.add_argument("--config", help="YAML file with vslam settings (not the camera: use --camera)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one setting, e.g. --set frontend.motion=3d3d (repeatable)")
    p.add_argument("--max-frames", type=int, help="stop after N frames")
    p.add_argument("--start-frame", type=int, default=0, help="first frame to use")
    p.add_argument("--viz", metavar="rerun[:FILE.rrd]",
                   help="stream to a rerun viewer, or record to FILE.rrd (needs the viz extra)")
    p.add_argument("--viz-scale", type=float, default=1.0, metavar="S",
                   help="log images at S times their size, e.g. 0.5 (smaller recordings; 0 < S <= 1)")
    p.add_argument("--viz-every", type=int, default=1, metavar="N",
                   help="log the image of every N-th frame only (poses and map every frame)")
    p.add_argument("--dense", action="store_true",
                   help="also fuse the keyframes into a TSDF mesh: mesh.ply, dense.ply (rgbd/stereo; dense extra)")
    p.add_argument("--trajectory-format", choices=["tum", "kitti", "euroc"], default="tum",
                   help="also write the trajectory in this format (trajectory_kitti.txt, trajectory_euroc.csv); "
                        "trajectory.txt stays TUM")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--map", dest="map_dir", metavar="MAP_DIR",
                   help="continue the map saved by an earlier run (its output folder): frames are placed in it "
                        "and mapping extends it; the trajectory is in its world frame")
    add_gt_argument(p)
    p.set_defaults(func=run)
    return p


def map_line(s: dict) -> str:
    """``map loaded: DIR (N keyframes); first frame placed at frame F ...`` of a ``--map`` run."""
    placed = s.get("placed_at_frame")
    if placed is not None:
        where = (f"first frame placed at frame {placed} (against its keyframe {s.get('placed_keyframe')}, "
                 f"{s.get('placed_inliers')} inliers)")
    else:
        joins = len(s.get("merges") or [])
        where = (f"no frame placed in it: the session started its own segment ({joins} join"
                 f"{'' if joins == 1 else 's'} to the map later)")
    return f"map loaded: {s['map_loaded']} ({s.get('map_keyframes_loaded', '?')} keyframes); {where}"


def run(args: argparse.Namespace) -> int:
    from vslam.api import run_path
    from vslam.errors import VslamError

    if not 0.0 < args.viz_scale <= 1.0:
        raise VslamError(f"--viz-scale {args.viz_scale:g}: use a factor in (0, 1], e.g. 0.5")
    viz_options = {"image_scale": 1.0 / args.viz_scale, "image_every": args.viz_every}
    with compile_notice():  # one line before a first run compiles the numeric kernels
        result = run_path(
            args.path, args.output, sensor=args.sensor, dataset=args.dataset, config=args.config,
            overrides=args.overrides, max_frames=args.max_frames, start_frame=args.start_frame,
            progress=not args.no_progress, viz=args.viz, dense=args.dense, camera=args.camera,
            trajectory_format=args.trajectory_format, topics=args.topics, viz_options=viz_options,
            map_dir=args.map_dir, gt=args.gt, imu=args.imu,
        )
    s = result.stats
    line = f"{s['tracked']}/{s['frames']} frames tracked, {s.get('lost', 0)} lost, " \
           f"{s.get('skipped_frames', 0)} skipped (unreadable), " \
           f"{s.get('keyframes', 0)} keyframes, {s.get('map_points', 0)} map points, {s['fps']:.1f} frames/s"
    print(line)
    if "map_loaded" in s:
        print(map_line(s))
    if "camera" in s:
        print(f"camera: {s['camera']}")
    if "dropped_frames" in s:
        print(f"live: {s['captured_frames']} frames captured, {s['dropped_frames']} dropped while the tracker was busy")
    if "imu_initialized" in s:
        print(_imu_line(s))
    if ate_line(s):
        print(ate_line(s))
    if "trajectory_export" in s:
        print(f"trajectory ({args.trajectory_format}): {s['trajectory_export']}")
    if "dense" in s:
        d = s["dense"]
        print(f"dense map: {d.get('mesh_vertices', d.get('vertices', '?'))} mesh vertices -> {d.get('mesh', '')}")
    print(f"results in {Path(args.output)}")
    return 0


def _imu_line(s: dict) -> str:
    """The summary line of an inertial run's IMU initialization."""
    if not s["imu_initialized"]:
        return f"IMU not initialized ({s.get('imu_init_reason', '')})"
    if s.get("imu_init_source") == "map":
        return f"IMU initialized at frame {s['imu_init_frame']} from the loaded map (its gravity, scale and biases)"
    return (f"IMU initialized at frame {s['imu_init_frame']} after {s['imu_init_time_s']:.2f} s of motion"
            + (f", scale {s['imu_scale']:.4f}" if "imu_scale" in s else ""))
