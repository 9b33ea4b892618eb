"""Dense metric map: TSDF fusion of depth maps along known poses, mesh and point-cloud extraction.

Each frame's depth (RGB-D sensor depth, or SGBM stereo depth from :mod:`stereo_depth`) is fused
into a truncated signed distance volume (Curless & Levoy, "A Volumetric Method for Building
Complex Models from Range Images", SIGGRAPH 1996; the running weighted average of eq. 3-4, as in
KinectFusion, Newcombe et al., ISMAR 2011), stored sparsely in hashed voxel blocks (Open3D's
``ScalableTSDFVolume``; Nießner et al., "Real-time 3D Reconstruction at Scale using Voxel
Hashing", SIGGRAPH Asia 2013). The surface is the zero level set, extracted by marching cubes
(Lorensen & Cline, SIGGRAPH 1987) as a coloured triangle mesh, and as a point cloud.

Open3D is an optional dependency (the ``dense`` extra, pinned to 0.19.0: 0.20.0's
``ScalableTSDFVolume`` returns an empty mesh); it is imported only when fusion runs.

Example:
    >>> seq = SyntheticSequence(SyntheticConfig(n_frames=10))          # doctest: +SKIP
    >>> result = fuse_tsdf(seq, [f.T_world_cam for f in seq])           # doctest: +SKIP
    >>> result.save("out")                                              # doctest: +SKIP
    {'mesh': PosixPath('out/mesh.ply'), 'dense': PosixPath('out/dense.ply')}
"""
from __future__ import annotations

import contextlib
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import cv2
import numpy as np

from vslam.datasets.frame import Frame
from vslam.errors import GeometryError, VslamError
from vslam.geometry.camera import PinholeCamera
from vslam.geometry.lie import inv_se3
from vslam.reconstruction.ply import write_mesh, write_point_cloud
from vslam.reconstruction.stereo_depth import StereoDepthConfig, depth_from_stereo

log = logging.getLogger(__name__)

DEPTH_SOURCES = ("auto", "depth", "stereo")


def import_open3d():
    """``open3d``, or a :class:`VslamError` saying how to install it."""
    try:
        import open3d as o3d  # noqa: PLC0415 - optional dependency
    except ImportError as exc:
        raise VslamError(
            f"dense reconstruction needs Open3D ({exc}); install the dense extra: pip install 'vslam[dense]'"
        ) from None
    return o3d


@dataclass(frozen=True)
class TSDFConfig:
    """TSDF fusion settings (metres).

    Attributes:
        voxel_size: voxel edge length.
        sdf_trunc: truncation distance of the signed distance; None = 4 voxels.
        depth_max: depths beyond this are not fused (depth noise grows with distance).
        depth_min: depths below this are not fused.
        depth_source: ``depth`` (the frame's RGB-D depth), ``stereo`` (SGBM on the rectified
            pair) or ``auto`` (depth when the frame has it, else stereo).
        stereo: SGBM settings for stereo depth.
        threads: OpenMP threads Open3D may use while fusing; None = ``OMP_NUM_THREADS`` when
            the user set it, else half the CPU cores (at least one). Open3D's OpenMP threads spin-wait: on a busy 2-core machine two threads made
            integration 5-10x slower than one (TUM fr1 640x480, 1 cm voxels: 25-47 ms vs
            175-360 ms per frame).
    """

    voxel_size: float = 0.01
    sdf_trunc: float | None = None
    depth_max: float = 4.0
    depth_min: float = 0.0
    depth_source: str = "auto"
    stereo: StereoDepthConfig = field(default_factory=StereoDepthConfig)
    threads: int | None = None

    def __post_init__(self) -> None:
        if not self.voxel_size > 0:
            raise VslamError(f"TSDF voxel_size must be > 0, got {self.voxel_size}")
        if self.sdf_trunc is not None and not self.sdf_trunc > self.voxel_size:
            raise VslamError(f"TSDF sdf_trunc ({self.sdf_trunc}) must exceed voxel_size ({self.voxel_size})")
        if not self.depth_max > self.depth_min >= 0:
            raise VslamError(f"TSDF needs 0 <= depth_min < depth_max, got {self.depth_min}, {self.depth_max}")
        if self.depth_source not in DEPTH_SOURCES:
            raise VslamError(f"depth_source {self.depth_source!r} unknown; use one of {DEPTH_SOURCES}")

    @property
    def truncation(self) -> float:
        return float(self.sdf_trunc if self.sdf_trunc is not None else 4.0 * self.voxel_size)

    @property
    def n_threads(self) -> int | None:
        """Threads to hold Open3D to; None leaves the user's ``OMP_NUM_THREADS`` in charge."""
        if self.threads:
            return int(self.threads)
        if "OMP_NUM_THREADS" in os.environ or "OMP_DYNAMIC" in os.environ:
            return None
        return max(1, (os.cpu_count() or 2) // 2)


_CONTROLLER = None


@contextlib.contextmanager
def _omp_limit(n: int | None):
    """Hold Open3D's OpenMP loops to ``n`` threads while the block runs (process-wide).

    Open3D 0.19 sizes its OpenMP teams with ``utility::EstimateMaxThreads()``, which returns
    ``omp_get_max_threads()`` only when ``OMP_NUM_THREADS`` or ``OMP_DYNAMIC`` is set in the
    environment (it calls ``getenv`` each time) and otherwise the number of physical cores. So the
    variable is set for the duration of the call (if the user has not set it) and the OpenMP
    limit itself is applied with threadpoolctl.
    """
    global _CONTROLLER
    if n is None:
        yield
        return
    added = "OMP_NUM_THREADS" not in os.environ and "OMP_DYNAMIC" not in os.environ
    if added:
        os.environ["OMP_NUM_THREADS"] = str(n)
    try:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:  # pragma: no cover - threadpoolctl is a dependency
            yield
            return
        if _CONTROLLER is None:
            _CONTROLLER = ThreadpoolController()
        with _CONTROLLER.limit(limits=n, user_api="openmp"):
            yield
    finally:
        if added:
            os.environ.pop("OMP_NUM_THREADS", None)


@dataclass
class DenseResult:
    """A fused dense map.

    Attributes:
        vertices: ``(V, 3)`` float64 mesh vertices, world frame.
        faces: ``(F, 3)`` int32 triangles.
        vertex_colors: ``(V, 3)`` uint8 RGB.
        points: ``(P, 3)`` float64 surface points (the TSDF zero crossings), world frame.
        point_colors: ``(P, 3)`` uint8 RGB.
        point_normals: ``(P, 3)`` or None.
        n_frames: frames fused.
        timings: ``depth_ms_per_frame``, ``integrate_ms_per_frame``, ``mesh_s``, ``cloud_s``.
    """

    vertices: np.ndarray
    faces: np.ndarray
    vertex_colors: np.ndarray
    points: np.ndarray
    point_colors: np.ndarray
    point_normals: np.ndarray | None = None
    n_frames: int = 0
    timings: dict = field(default_factory=dict)

    def save(self, folder: str | Path, binary: bool = True) -> dict[str, Path]:
        """Write ``folder/mesh.ply`` (triangle mesh) and ``folder/dense.ply`` (point cloud)."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        mesh = write_mesh(folder / "mesh.ply", self.vertices.astype(np.float32), self.faces,
                          colors=self.vertex_colors, binary=binary)
        normals = self.point_normals.astype(np.float32) if self.point_normals is not None else None
        dense = write_point_cloud(folder / "dense.ply", self.points.astype(np.float32), colors=self.point_colors,
                                  normals=normals, binary=binary)
        return {"mesh": mesh, "dense": dense}

    def summary(self) -> dict:
        lo = self.vertices.min(axis=0) if len(self.vertices) else np.zeros(3)
        hi = self.vertices.max(axis=0) if len(self.vertices) else np.zeros(3)
        return {
            "frames_fused": int(self.n_frames), "vertices": int(len(self.vertices)), "triangles": int(len(self.faces)),
            "points": int(len(self.points)), "extent_m": [round(float(v), 3) for v in hi - lo],
            **{k: round(float(v), 3) for k, v in self.timings.items()},
        }


# ---------------------------------------------------------------------------------------------
# per-frame depth
# ---------------------------------------------------------------------------------------------
def _rgb(image: np.ndarray) -> np.ndarray:
    """uint8 RGB ``(H, W, 3)`` from a BGR or gray frame image."""
    if image.ndim == 2:
        return np.ascontiguousarray(np.repeat(image[:, :, None], 3, axis=2))
    return np.ascontiguousarray(cv2.cvtColor(image, cv2.COLOR_BGR2RGB))


def _undistort_maps(camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    return cv2.initUndistortRectifyMap(camera.K, camera.dist_coeffs, None, camera.K,
                                       (camera.width, camera.height), cv2.CV_32FC1)


def frame_depth(frame: Frame, config: TSDFConfig = TSDFConfig()) -> tuple[np.ndarray, np.ndarray, PinholeCamera]:
    """``(rgb uint8 (H, W, 3), depth float32 (H, W) metres, ideal pinhole camera)`` of one frame.

    Sensor depth of a distorted camera (TUM fr1) is undistorted with the colour (nearest
    neighbour for depth, so no depth is invented across edges); stereo depth comes from SGBM on
    the rectified pair. Depths outside ``[depth_min, depth_max]`` are zeroed.
    """
    cam = frame.camera
    source = config.depth_source
    if source == "auto":
        source = "depth" if frame.depth is not None else "stereo"
    if source == "depth":
        if frame.depth is None:
            raise VslamError(f"frame {frame.index} ({frame.path}) has no depth map; open the sequence as rgbd "
                             "or use depth_source='stereo'")
        depth = np.asarray(frame.depth, dtype=np.float32)
        rgb = _rgb(frame.image)
        if cam.is_distorted:
            mx, my = _undistort_maps(cam)
            rgb = cv2.remap(rgb, mx, my, cv2.INTER_LINEAR)
            depth = cv2.remap(depth, mx, my, cv2.INTER_NEAREST)
            cam = PinholeCamera(cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height, baseline=cam.baseline)
    else:
        if frame.image_right is None:
            raise VslamError(f"frame {frame.index} ({frame.path}) has neither depth nor a right image; dense "
                             "reconstruction needs an rgbd or stereo sequence")
        if cam.is_distorted:
            raise VslamError(f"frame {frame.index}: stereo depth needs rectified images, the camera has distortion")
        depth = depth_from_stereo(frame.gray, frame.image_right, cam, config=config.stereo)
        rgb = _rgb(frame.image)
    if depth.shape != rgb.shape[:2]:
        raise VslamError(f"frame {frame.index}: depth {depth.shape} and image {rgb.shape[:2]} differ in size")
    depth = np.where((depth >= config.depth_min) & (depth <= config.depth_max) & np.isfinite(depth), depth, 0.0)
    return rgb, depth.astype(np.float32), cam


# ---------------------------------------------------------------------------------------------
# fusion
# ---------------------------------------------------------------------------------------------
class TSDFFusion:
    """Incremental TSDF fusion: :meth:`integrate` frames one by one, then :meth:`extract`.

    Example:
        >>> fusion = TSDFFusion(TSDFConfig(voxel_size=0.02))          # doctest: +SKIP
        >>> for frame in frames:                                       # doctest: +SKIP
        ...     fusion.integrate_frame(frame, frame.T_world_cam)
        >>> result = fusion.extract()                                  # doctest: +SKIP
    """

    def __init__(self, config: TSDFConfig = TSDFConfig()):
        self.config = config
        self._o3d = import_open3d()
        o3d = self._o3d
        self.volume = o3d.pipelines.integration.ScalableTSDFVolume(
            voxel_length=float(config.voxel_size), sdf_trunc=config.truncation,
            color_type=o3d.pipelines.integration.TSDFVolumeColorType.RGB8,
        )
        self.n_frames = 0
        self._t_depth = 0.0
        self._t_integrate = 0.0
        self._intrinsics: dict = {}

    def _intrinsic(self, cam: PinholeCamera):
        key = (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)
        if key not in self._intrinsics:
            self._intrinsics[key] = self._o3d.camera.PinholeCameraIntrinsic(
                int(cam.width), int(cam.height), float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy))
        return self._intrinsics[key]

    def integrate(self, rgb: np.ndarray, depth: np.ndarray, camera: PinholeCamera, T_world_cam: np.ndarray) -> None:
        """Fuse one RGB ``uint8 (H, W, 3)`` + depth ``float32 (H, W)`` metres image seen from ``T_world_cam``."""
        T_world_cam = np.asarray(T_world_cam, dtype=np.float64)
        if T_world_cam.shape != (4, 4) or not np.all(np.isfinite(T_world_cam)):
            raise GeometryError(f"TSDF pose must be a finite 4x4 T_world_cam, got shape {T_world_cam.shape}")
        o3d = self._o3d
        t0 = time.perf_counter()
        with _omp_limit(self.config.n_threads):
            rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
                o3d.geometry.Image(np.ascontiguousarray(rgb, dtype=np.uint8)),
                o3d.geometry.Image(np.ascontiguousarray(depth, dtype=np.float32)),
                depth_scale=1.0, depth_trunc=float(self.config.depth_max), convert_rgb_to_intensity=False,
            )
            # Open3D wants the extrinsic T_cam_world (world -> camera)
            self.volume.integrate(rgbd, self._intrinsic(camera), inv_se3(T_world_cam))
        self._t_integrate += time.perf_counter() - t0
        self.n_frames += 1

    def integrate_frame(self, frame: Frame, T_world_cam: np.ndarray | None = None) -> None:
        """Fuse a :class:`Frame` (its depth or SGBM stereo depth) at ``T_world_cam`` (default: the frame's)."""
        if T_world_cam is None:
            T_world_cam = frame.T_world_cam
        if T_world_cam is None:
            raise VslamError(f"frame {frame.index} ({frame.path}) has no pose; pass T_world_cam")
        t0 = time.perf_counter()
        rgb, depth, cam = frame_depth(frame, self.config)
        self._t_depth += time.perf_counter() - t0
        self.integrate(rgb, depth, cam, T_world_cam)

    def extract(self, point_cloud: bool = True) -> DenseResult:
        """Marching-cubes mesh and zero-crossing point cloud of everything fused so far."""
        t0 = time.perf_counter()
        with _omp_limit(self.config.n_threads):
            mesh = self.volume.extract_triangle_mesh()
        t_mesh = time.perf_counter() - t0
        vertices = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(mesh.triangles, dtype=np.int32).reshape(-1, 3)
        vcol = _to_u8(np.asarray(mesh.vertex_colors), len(vertices))
        t0 = time.perf_counter()
        points = np.zeros((0, 3))
        pcol = np.zeros((0, 3), np.uint8)
        normals = None
        if point_cloud:
            with _omp_limit(self.config.n_threads):
                pcd = self.volume.extract_point_cloud()
            points = np.asarray(pcd.points, dtype=np.float64).reshape(-1, 3)
            pcol = _to_u8(np.asarray(pcd.colors), len(points))
            if pcd.has_normals():
                normals = np.asarray(pcd.normals, dtype=np.float64).reshape(-1, 3)
        t_cloud = time.perf_counter() - t0
        n = max(self.n_frames, 1)
        timings = {
            "depth_ms_per_frame": 1000.0 * self._t_depth / n,
            "integrate_ms_per_frame": 1000.0 * self._t_integrate / n,
            "mesh_s": t_mesh, "cloud_s": t_cloud,
        }
        log.info("TSDF: %d frames -> %d vertices, %d triangles, %d points (integrate %.1f ms/frame, mesh %.2f s)",
                 self.n_frames, len(vertices), len(faces), len(points), timings["integrate_ms_per_frame"], t_mesh)
        return DenseResult(vertices, faces, vcol, points, pcol, normals, self.n_frames, timings)


def _to_u8(colors: np.ndarray, n: int) -> np.ndarray:
    if colors.size == 0:
        return np.full((n, 3), 200, np.uint8)
    return np.clip(np.round(colors.reshape(-1, 3) * 255.0), 0, 255).astype(np.uint8)


def fuse_tsdf(
    frames: Iterable[Frame],
    T_world_cam: Sequence[np.ndarray | None] | np.ndarray | None = None,
    camera: PinholeCamera | None = None,
    voxel_size: float = 0.01,
    sdf_trunc: float | None = 0.04,
    depth_max: float = 4.0,
    depth_min: float = 0.0,
    depth_source: str = "auto",
    stereo: StereoDepthConfig | None = None,
    point_cloud: bool = True,
    config: TSDFConfig | None = None,
    progress=None,
) -> DenseResult:
    """Fuse ``frames`` at poses ``T_world_cam`` into a TSDF and extract a mesh and a point cloud.

    Args:
        frames: :class:`Frame` records with colour and either ``depth`` or a rectified
            ``image_right`` (then ``camera.baseline`` must be set).
        T_world_cam: one 4x4 pose per frame (``(N, 4, 4)`` or a list; a None entry skips that
            frame); None uses each frame's own ``T_world_cam`` (ground truth).
        camera: overrides ``frame.camera`` (e.g. a recalibrated camera); None keeps it.
        voxel_size, sdf_trunc, depth_max, depth_min, depth_source, stereo: see :class:`TSDFConfig`
            (``sdf_trunc`` None = 4 voxels); ignored when ``config`` is given.
        progress: a tqdm-like factory (``progress(iterable, total=, desc=)``) wrapping the frames
            (e.g. ``functools.partial(tqdm, file=sys.stderr)``); None shows nothing.

    Raises:
        VslamError: Open3D missing, a frame without depth/stereo, poses and frames of different length.
    """
    if config is None:
        if sdf_trunc is not None and sdf_trunc <= voxel_size:
            sdf_trunc = None  # the default 4 cm is meant for 1 cm voxels; scale it with coarser ones
        config = TSDFConfig(voxel_size, sdf_trunc, depth_max, depth_min, depth_source,
                            stereo if stereo is not None else StereoDepthConfig())
    fusion = TSDFFusion(config)
    poses = None if T_world_cam is None else list(T_world_cam)
    n = 0
    if progress is not None:
        frames = progress(frames, total=len(poses) if poses is not None else None, desc="TSDF fusion", unit="frame")
    for i, frame in enumerate(frames):
        if poses is not None:
            if i >= len(poses):
                raise VslamError(f"fuse_tsdf: more frames than poses ({len(poses)}); pass one T_world_cam per frame")
            pose = poses[i]
            if pose is None:
                continue
        else:
            pose = None
        if camera is not None:
            frame = Frame(frame.index, frame.timestamp, frame.image, camera, frame.image_right, frame.depth,
                          frame.T_world_cam, frame.path)
        fusion.integrate_frame(frame, pose)
        n = i + 1
    if poses is not None and n and n < len(poses) and any(p is not None for p in poses[n:]):
        log.warning("fuse_tsdf: %d poses but only %d frames", len(poses), n)
    if fusion.n_frames == 0:
        raise VslamError("fuse_tsdf: no frame was fused (no frames, or no pose for any frame)")
    return fusion.extract(point_cloud=point_cloud)


__all__ = ["DEPTH_SOURCES", "DenseResult", "TSDFConfig", "TSDFFusion", "frame_depth", "fuse_tsdf", "import_open3d"]
