"""What several sub-commands share: the ``--gt`` option, the ATE line of their summary, and the
one line printed before the numeric kernels compile on a first run."""
from __future__ import annotations

import argparse
import sys

#: printed (stderr) before a run whose numeric kernels are not compiled yet
COMPILE_NOTICE = "compiling numeric kernels once, about 30 s (cached for the next runs) ..."


def add_gt_argument(p: argparse.ArgumentParser, what: str = "the sequence's own") -> None:
    """``--gt FILE|none``."""
    p.add_argument("--gt", metavar="FILE|none",
                   help=f"ground truth to evaluate against (TUM, KITTI or EuRoC trajectory; default: {what}); "
                        "none: no evaluation")


def ate_line(stats: dict) -> str | None:
    """``ATE RMSE 0.0123 m over 9 poses (ground truth FILE, frame rgb)``, or None without an ATE."""
    if "ate_rmse" not in stats:
        return None
    scale = "; Sim(3)-aligned: monocular scale is arbitrary" if stats.get("sensor") == "mono" else ""
    where = f"ground truth {stats['gt_file']}, frame {stats.get('gt_frame', '?')}" if stats.get("gt_file") else \
        "ground truth"
    return f"ATE RMSE {stats['ate_rmse']:.4f} m over {stats.get('matched_poses', 0)} poses ({where}{scale})"


def compile_notice():
    """A context manager: inside it, :data:`COMPILE_NOTICE` is printed (stderr) just before the
    numeric kernels compile from a cold cache (a fresh install), which is ~30 s without output
    otherwise (:func:`vslam.stream.compile_notice`)."""
    from vslam.stream import compile_notice as notice

    return notice(lambda: print(COMPILE_NOTICE, file=sys.stderr, flush=True))
