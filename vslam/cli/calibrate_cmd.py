"""``vslam calibrate SOURCE --board COLSxROWS --square M -o camera.yaml``: checkerboard / ChArUco calibration."""
from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "calibrate", help="calibrate a camera from checkerboard or ChArUco views",
        description="Calibrate a camera (OpenCV) from an image folder or a video showing a checkerboard "
                    "(or ChArUco board); prints the RMS reprojection error, each view's error and outlier views, "
                    "warns about a principal point far from the centre, extreme distortion or parts of the image "
                    "no view covers (named), and writes a camera.yaml that `vslam run --camera` reads.",
    )
    p.add_argument("source", help="image folder or video file")
    p.add_argument("--board", required=True, metavar="COLSxROWS",
                   help="checkerboard inner corners, e.g. 9x6 (ChArUco: squares, e.g. 7x5)")
    p.add_argument("--square", required=True, type=float, metavar="METRES", help="square side in metres")
    p.add_argument("--charuco", metavar="DICT", help="a ChArUco board with this ArUco dictionary, e.g. DICT_5X5_100")
    p.add_argument("--marker", type=float, metavar="METRES", help="ChArUco marker side (default 0.75 * square)")
    p.add_argument("--fisheye", action="store_true", help="the fisheye (Kannala-Brandt / equidistant) model")
    p.add_argument("--every", type=int, default=1, metavar="N", help="use every N-th image / video frame")
    p.add_argument("--output", "-o", required=True, help="camera YAML to write")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from vslam.calibrate import Board, calibrate_source, parse_board
    from vslam.errors import CalibrationError

    if not args.square > 0:
        raise CalibrationError(f"--square must be positive metres, got {args.square}")
    cols, rows = parse_board(args.board)
    board = Board(cols, rows, args.square, args.charuco, args.marker)
    result = calibrate_source(args.source, board, args.output, fisheye=args.fisheye, every=args.every)
    print(result.summary())
    print(f"wrote {args.output}")
    return 0
