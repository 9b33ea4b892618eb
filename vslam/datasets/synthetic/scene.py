"""The synthetic indoor scene: a textured room with axis-aligned boxes, and its texture atlas.

World frame: x and y horizontal, z up (gravity along -z); the floor is ``z = 0``. Every surface is
an axis-aligned rectangle (:class:`Face`) textured with a unique, non-repeating collage of the
photographs shipped inside the scikit-image wheel (``skimage/data/*.png|jpg``, read from disk so no
network/pooch download is ever attempted). The collage gives every surface strong corner texture
for ORB/SIFT/KLT while staying distinctive enough for loop detection.

The atlas stores every face at ``texels_per_metre`` (mip level 0) plus two Gaussian-pyramid levels
(``cv2.pyrDown``) side by side in one image, so the renderer samples all faces with one
``cv2.remap`` (Williams, "Pyramidal parametrics", SIGGRAPH 1983, for the mip-map idea).
"""
from __future__ import annotations

import functools
import logging
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from vslam.errors import ConfigError, DatasetError

log = logging.getLogger(__name__)

# Photographs inside the scikit-image wheel (no download needed). Grayscale ones get a colour tint.
TEXTURE_FILES = (
    "astronaut.png", "coffee.png", "chelsea.png", "camera.png", "rocket.jpg", "brick.png",
    "grass.png", "gravel.png", "coins.png", "moon.png", "motorcycle_left.png", "hubble_deep_field.jpg",
    "ihc.png", "retina.jpg", "text.png", "page.png", "cell.png",
)
MIP_LEVELS = 3
_PAD = 16  # level-0 texels of padding around each face in the atlas (bilinear + pyramid bleed)


@dataclass(frozen=True)
class Box:
    """An axis-aligned box ``lo <= X <= hi`` (metres, world frame)."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    name: str = "box"


@dataclass(frozen=True)
class Face:
    """One axis-aligned textured rectangle of the scene.

    The face lies in the plane ``X[axis] = offset``; its visible side is the one ``normal_sign``
    points to (a ray from camera centre ``C`` can see it iff ``normal_sign * (C[axis] - offset) > 0``).
    Its texture's columns run along world axis ``u_axis`` (from ``u_range[0]``) and its rows along
    ``v_axis``, from ``v_range[1]`` downwards if ``v_flip`` (walls: row 0 at the top) else from
    ``v_range[0]``. ``atlas_uv`` is the level-0 atlas pixel of the face's texture origin.
    """

    axis: int
    offset: float
    normal_sign: int
    u_axis: int
    v_axis: int
    u_range: tuple[float, float]
    v_range: tuple[float, float]
    v_flip: bool
    name: str
    atlas_uv: tuple[int, int] = (0, 0)

    def corners(self) -> np.ndarray:
        """The 4 corners ``(4, 3)`` in world coordinates, in polygon order."""
        out = np.zeros((4, 3))
        out[:, self.axis] = self.offset
        (u0, u1), (v0, v1) = self.u_range, self.v_range
        out[:, self.u_axis] = [u0, u1, u1, u0]
        out[:, self.v_axis] = [v0, v0, v1, v1]
        return out


@dataclass(frozen=True)
class SceneSpec:
    """Geometry of the default scene: a ``6 x 4 x 3`` m room and furniture boxes standing in it."""

    room_lo: tuple[float, float, float] = (-3.0, -2.0, 0.0)
    room_hi: tuple[float, float, float] = (3.0, 2.0, 3.0)
    boxes: tuple[Box, ...] = (
        Box((-0.5, -0.3, 0.0), (0.5, 0.3, 0.75), "table"),
        Box((0.05, -0.15, 0.75), (0.35, 0.2, 1.0), "parcel"),
        Box((-3.0, 0.6, 0.0), (-2.4, 1.8, 1.9), "cabinet"),
        Box((2.2, -2.0, 0.0), (3.0, -1.4, 1.2), "shelf"),
        Box((1.2, 1.3, 0.0), (1.8, 1.9, 0.6), "crate"),
        Box((-1.5, -2.0, 0.0), (-0.9, -1.5, 0.9), "chest"),
        Box((2.6, 1.6, 0.0), (3.0, 2.0, 3.0), "pillar"),
        Box((-1.0, 1.5, 0.0), (0.4, 2.0, 0.45), "bench"),
    )
    texels_per_metre: float = 200.0
    texture_seed: int = 7


@dataclass
class Scene:
    """Faces plus the texture atlas (``uint8`` BGR, all mip levels side by side)."""

    spec: SceneSpec
    faces: list[Face]
    atlas: np.ndarray
    level_x: tuple[float, ...]  # atlas x offset of each mip level
    texels_per_metre: float = field(default=200.0)


def _faces_of_box(lo, hi, inward: bool, name: str) -> list[Face]:
    faces = []
    for axis in range(3):
        u_axis, v_axis = [(1, 2), (0, 2), (0, 1)][axis]
        v_flip = axis != 2
        for side, offset in ((0, lo[axis]), (1, hi[axis])):
            outward = -1 if side == 0 else 1
            sign = -outward if inward else outward
            faces.append(Face(
                axis, float(offset), sign, u_axis, v_axis,
                (float(lo[u_axis]), float(hi[u_axis])), (float(lo[v_axis]), float(hi[v_axis])),
                v_flip, f"{name}/{'xyz'[axis]}{'-+'[side]}",
            ))
    return faces


def scene_faces(spec: SceneSpec) -> list[Face]:
    """All faces of the room (seen from inside) and of the boxes (seen from outside).

    Box faces lying on the floor or against a room face can never be seen; they are dropped.
    """
    faces = _faces_of_box(spec.room_lo, spec.room_hi, inward=True, name="room")
    for box in spec.boxes:
        for f in _faces_of_box(box.lo, box.hi, inward=False, name=box.name):
            on_room = f.offset in (spec.room_lo[f.axis], spec.room_hi[f.axis])
            if not on_room:
                faces.append(f)
    return faces


@functools.lru_cache(maxsize=None)
def _photos() -> tuple[np.ndarray, ...]:
    """The scikit-image sample photographs as BGR ``uint8`` images (read from the installed wheel)."""
    import skimage
    from PIL import Image  # Pillow (a matplotlib dependency): no libpng warnings on iCCP chunks

    folder = Path(skimage.__file__).parent / "data"
    out = []
    for name in TEXTURE_FILES:
        try:
            with Image.open(folder / name) as im:
                rgb = np.asarray(im.convert("RGB"))
        except OSError:
            log.debug("texture %s not readable, skipped", name)
            continue
        if min(rgb.shape[:2]) < 96:
            continue
        out.append(np.ascontiguousarray(rgb[:, :, ::-1]))
    if len(out) < 4:
        raise DatasetError(
            f"{folder}: only {len(out)} of the scikit-image sample photographs could be read; "
            "the synthetic scene needs them for textures: reinstall scikit-image"
        )
    return tuple(out)


def _collage(rng: np.random.Generator, height: int, width: int, texels_per_metre: float) -> np.ndarray:
    """A ``(height, width, 3)`` non-repeating texture: random photo crops in a random brick layout.

    Rows of patches 0.3-0.9 m tall, patches 0.3-1.2 m wide, each a random crop of a random
    photograph, randomly flipped/rotated, tinted and rescaled; a few smaller "posters" on top.
    """
    photos = _photos()
    out = np.zeros((height, width, 3), np.uint8)
    y = 0
    while y < height:
        h = int(rng.uniform(0.3, 0.9) * texels_per_metre)
        x = -int(rng.uniform(0.0, 0.5) * texels_per_metre)
        while x < width:
            w = int(rng.uniform(0.3, 1.2) * texels_per_metre)
            _paste(rng, out, photos, x, y, w, h)
            x += w
        y += h
    n_posters = int(rng.poisson(height * width / (1.5 * texels_per_metre) ** 2)) + 1
    for _ in range(n_posters):
        w = int(rng.uniform(0.15, 0.5) * texels_per_metre)
        h = int(rng.uniform(0.15, 0.5) * texels_per_metre)
        _paste(rng, out, photos, int(rng.integers(-w // 2, width)), int(rng.integers(-h // 2, height)), w, h)
    return out


def _paste(rng, out, photos, x, y, w, h) -> None:
    H, W = out.shape[:2]
    x0, y0, x1, y1 = max(x, 0), max(y, 0), min(x + w, W), min(y + h, H)
    if x1 <= x0 or y1 <= y0:
        return
    img = photos[int(rng.integers(len(photos)))]
    k = int(rng.integers(4))  # quarter turns, applied to the crop
    flip = rng.random() < 0.5
    ph, pw = (h, w) if k % 2 == 0 else (w, h)  # the crop's shape before turning
    ih, iw = img.shape[:2]
    # crop with the patch's aspect ratio, 35-100 % of the photo's size
    s = rng.uniform(0.35, 1.0)
    ch = min(ih, max(16, int(min(ih, iw * ph / pw) * s)))
    cw = min(iw, max(16, int(ch * pw / ph)))
    cy0 = int(rng.integers(0, ih - ch + 1))
    cx0 = int(rng.integers(0, iw - cw + 1))
    crop = img[cy0:cy0 + ch, cx0:cx0 + cw]
    if k:
        crop = cv2.rotate(crop, (cv2.ROTATE_90_COUNTERCLOCKWISE, cv2.ROTATE_180, cv2.ROTATE_90_CLOCKWISE)[k - 1])
    if flip:
        crop = cv2.flip(crop, 1)
    cw, ch = crop.shape[1], crop.shape[0]
    interp = cv2.INTER_AREA if cw > w else cv2.INTER_LINEAR
    patch = cv2.resize(crop, (w, h), interpolation=interp).astype(np.float32)
    gain = rng.uniform(0.6, 1.25, size=3).astype(np.float32)  # colour tint (greyscale photos too)
    patch = np.clip(patch * gain + rng.uniform(-20, 20), 0, 255).astype(np.uint8)
    out[y0:y1, x0:x1] = patch[y0 - y:y1 - y, x0 - x:x1 - x]


def _pack(sizes: list[tuple[int, int]], max_width: int) -> tuple[list[tuple[int, int]], int, int]:
    """Shelf-pack ``(w, h)`` rectangles, tallest first; returns origins, total width, height."""
    order = sorted(range(len(sizes)), key=lambda i: -sizes[i][1])
    origins: list[tuple[int, int]] = [(0, 0)] * len(sizes)
    x = y = shelf_h = width = 0
    for i in order:
        w, h = sizes[i]
        if x + w > max_width and x > 0:
            y += shelf_h
            x = shelf_h = 0
        origins[i] = (x, y)
        x += w
        shelf_h = max(shelf_h, h)
        width = max(width, x)
    return origins, width, y + shelf_h


def build_scene(spec: SceneSpec = SceneSpec()) -> Scene:
    """Build faces and the texture atlas (about a second; use :func:`default_scene` to cache)."""
    rng = np.random.default_rng(spec.texture_seed)
    tpm = spec.texels_per_metre
    faces = scene_faces(spec)
    sizes = []
    for f in faces:
        w = int(np.ceil((f.u_range[1] - f.u_range[0]) * tpm)) + 2 * _PAD
        h = int(np.ceil((f.v_range[1] - f.v_range[0]) * tpm)) + 2 * _PAD
        sizes.append((w, h))
    origins, width, height = _pack(sizes, max_width=4096)
    # multiples of 4 so the pyramid levels align exactly: level-L pixel i <-> level-0 pixel 2^L i
    width = -(-width // 4) * 4
    height = -(-height // 4) * 4
    level0 = np.zeros((height, width, 3), np.uint8)
    placed = []
    for f, (w, h), (ox, oy) in zip(faces, sizes, origins):
        tex = _collage(rng, h - 2 * _PAD, w - 2 * _PAD, tpm)
        tex = cv2.copyMakeBorder(tex, _PAD, _PAD, _PAD, _PAD, cv2.BORDER_REFLECT_101)
        level0[oy:oy + h, ox:ox + w] = tex
        placed.append(_with_origin(f, ox + _PAD, oy + _PAD))
    # light pre-filter against aliasing, then the pyramid levels side by side
    level0 = cv2.GaussianBlur(level0, (0, 0), 0.6)
    levels = [level0]
    for _ in range(MIP_LEVELS - 1):
        levels.append(cv2.pyrDown(levels[-1]))
    total_w = sum(lv.shape[1] for lv in levels)
    atlas = np.zeros((height, total_w, 3), np.uint8)
    xs = []
    x = 0
    for lv in levels:
        atlas[: lv.shape[0], x:x + lv.shape[1]] = lv
        xs.append(float(x))
        x += lv.shape[1]
    if total_w >= 32767 or height >= 32767:
        raise ConfigError(
            f"texture atlas {total_w}x{height} exceeds cv2.remap's 32767 limit; lower texels_per_metre "
            f"(now {tpm})"
        )
    log.debug("synthetic scene: %d faces, atlas %dx%d", len(placed), total_w, height)
    return Scene(spec, placed, atlas, tuple(xs), tpm)


def _with_origin(f: Face, u: int, v: int) -> Face:
    return Face(f.axis, f.offset, f.normal_sign, f.u_axis, f.v_axis, f.u_range, f.v_range, f.v_flip, f.name, (u, v))


@functools.lru_cache(maxsize=4)
def default_scene(spec: SceneSpec = SceneSpec()) -> Scene:
    """The scene for ``spec``, built once per process."""
    return build_scene(spec)


def sample_surface_points(scene: Scene, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``n`` random points on the scene faces (area-weighted) and their face indices (for tests)."""
    areas = np.array([(f.u_range[1] - f.u_range[0]) * (f.v_range[1] - f.v_range[0]) for f in scene.faces])
    idx = rng.choice(len(areas), size=n, p=areas / areas.sum())
    axis = np.array([f.axis for f in scene.faces])[idx]
    u_axis = np.array([f.u_axis for f in scene.faces])[idx]
    v_axis = np.array([f.v_axis for f in scene.faces])[idx]
    offset = np.array([f.offset for f in scene.faces])[idx]
    u_range = np.array([f.u_range for f in scene.faces])[idx]
    v_range = np.array([f.v_range for f in scene.faces])[idx]
    rows = np.arange(n)
    pts = np.zeros((n, 3))
    pts[rows, axis] = offset
    pts[rows, u_axis] = rng.uniform(u_range[:, 0], u_range[:, 1])
    pts[rows, v_axis] = rng.uniform(v_range[:, 0], v_range[:, 1])
    return pts, idx


def distance_to_scene(points: np.ndarray, scene: Scene | None = None) -> np.ndarray:
    """Euclidean distance of ``(N, 3)`` world points to the nearest face (rectangle) of ``scene``
    (default: the default room): the exact ground truth for mapping accuracy checks."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    best = np.full(len(points), np.inf)
    for f in (scene or default_scene()).faces:
        lo, hi = np.zeros(3), np.zeros(3)
        lo[f.axis] = hi[f.axis] = f.offset
        lo[f.u_axis], hi[f.u_axis] = f.u_range
        lo[f.v_axis], hi[f.v_axis] = f.v_range
        best = np.minimum(best, np.linalg.norm(points - np.clip(points, lo, hi), axis=1))
    return best
