"""Metric and topological map outputs: PLY I/O, sparse export, TSDF dense fusion, stereo depth, topology.

Open3D (the ``dense`` extra) is needed only for TSDF fusion and is imported lazily.
"""
from __future__ import annotations

from vslam.reconstruction.dense import DenseResult, TSDFConfig, TSDFFusion, frame_depth, fuse_tsdf
from vslam.reconstruction.ply import PlyData, read_ply, write_mesh, write_ply, write_point_cloud
from vslam.reconstruction.rundir import reconstruct_run, select_frames
from vslam.reconstruction.sparse import export_sparse
from vslam.reconstruction.stereo_depth import StereoDepthConfig, default_max_depth, depth_from_stereo, disparity_sgbm
from vslam.reconstruction.topology import (
    EDGE_KINDS, nodes_from_poses, plot_topology, read_topology, write_topology,
)

__all__ = [
    "DenseResult", "EDGE_KINDS", "PlyData", "StereoDepthConfig", "TSDFConfig", "TSDFFusion", "default_max_depth",
    "depth_from_stereo", "disparity_sgbm", "export_sparse", "frame_depth", "fuse_tsdf", "nodes_from_poses",
    "plot_topology", "read_ply", "read_topology", "reconstruct_run", "select_frames", "write_mesh", "write_ply",
    "write_point_cloud", "write_topology",
]
