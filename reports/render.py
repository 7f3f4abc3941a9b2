"""Headless mesh thumbnails: a small vectorised numpy z-buffer rasteriser (no display, no GPU, no VTK).

Why a rasteriser of our own: a report renders (#shapes x (1 + 2 #methods)) thumbnails; pyvista/VTK is a
large dependency with a slow first off-screen image, and matplotlib's 3D axes sort whole polygons (no
z-buffer); a numpy z-buffer of triangles at 256 x 256 (2x supersampled) is fast, deterministic, and runs
on any bare CI machine (the costs compared: docs/PERFORMANCE.md, section 9).

Camera: orthographic, looking at the origin from (azimuth, elevation) degrees with +y up in the
canonical frame ([-1, 1]^3). The framing is fixed by a bounding box (``bounds``), so
renders of the GT and of every method of one shape line up when they are given the GT's box.

Shading: flat (one normal per face), two-sided: intensity = ambient + sum_k kd_k |n . l_k| + specular
|n . h|^p, so unoriented meshes (from unsigned fields, flipped faces) shade exactly like oriented ones.
Silhouettes and depth jumps are darkened for legibility. Colours may be uniform, per vertex
(interpolated barycentrically) or per face.
"""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

from methods.extractors.mesh_ops import drop_unreferenced_vertices

BACKGROUND = np.array([1.0, 1.0, 1.0])  # white: blends into the report's cards
BASE_COLOR = np.array([0.62, 0.72, 0.84])  # soft steel blue
GT_COLOR = np.array([0.78, 0.76, 0.72])  # warm grey (ground truth)
DEFAULT_VIEW = (-35.0, 25.0)  # azimuth, elevation in degrees
_SUPERSAMPLE = 2
_CHUNK_CANDIDATES = 1 << 21  # candidate (face, pixel) pairs per chunk: bounds memory to ~150 MB

# Lights in camera coordinates (x right, y up, z towards the viewer).
_LIGHTS = np.array([[-0.45, 0.8, 0.55], [0.75, 0.05, 0.65]])
_LIGHT_WEIGHTS = np.array([0.6, 0.28])
_AMBIENT = 0.2
_SPECULAR = 0.18
_SHININESS = 24.0


#: Rotations that take a frame whose up axis is the key to one whose up axis is +y (x -> y -> z
#: cycled, so each is a proper rotation); '' (up not stated) is taken as y.
_TO_Y_UP = {"": np.eye(3), "y": np.eye(3), "z": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
            "x": np.array([[0, 0, 1.0], [1, 0, 0], [0, 1, 0]])}


def camera_rotation(azimuth_deg: float, elevation_deg: float, up: str = "y") -> np.ndarray:
    """3x3 rotation whose rows are the camera's right, up and back (towards viewer) axes in world
    coordinates; camera coordinates are ``R @ p``. Azimuth turns about the world's ``up`` axis ('x',
    'y' or 'z'), elevation tilts towards it, so that axis points up in the image."""
    if up not in _TO_Y_UP:
        raise ValueError(f"up axis {up!r}: not one of 'x', 'y', 'z'")
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    back = np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    right = np.cross([0.0, 1.0, 0.0], back)
    right /= np.linalg.norm(right)
    up_axis = np.cross(back, right)
    return np.stack([right, up_axis, back]) @ _TO_Y_UP[up]


def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    bits = np.array([[i >> k & 1 for k in range(3)] for i in range(8)], dtype=float)
    return lo + bits * (hi - lo)


def _encode_png(rgb: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8), "RGB").save(buffer, format="PNG")
    return buffer.getvalue()


def _resolve_colors(colors, n_vertices: int, n_faces: int, default: np.ndarray):
    """(mode, array): mode 'uniform' (3,), 'vertex' (n,3) or 'face' (m,3), values in [0, 1]."""
    if colors is None:
        return "uniform", default
    c = np.asarray(colors, dtype=float)
    if c.size and c.max() > 1.0:  # 0..255 given
        c = c / 255.0
    if c.ndim == 1 and c.shape[0] in (3, 4):
        return "uniform", c[:3]
    if c.ndim == 2 and c.shape[1] in (3, 4):
        if c.shape[0] == n_vertices:
            return "vertex", c[:, :3]
        if c.shape[0] == n_faces:
            return "face", c[:, :3]
    raise ValueError(
        f"colors must be (3,), ({n_vertices}, 3) per vertex or ({n_faces}, 3) per face, got shape {c.shape}"
    )


def rasterize(screen: np.ndarray, depth: np.ndarray, faces: np.ndarray, width: int, height: int):
    """Z-buffer of triangles already in pixel coordinates.

    screen (n,2): x right, y down, pixel (i, j) has its centre at (i + 0.5, j + 0.5); depth (n,): smaller
    is closer. Returns (face_id (H,W) int64, -1 where empty; barycentric weights (H,W,3)).
    Vectorised over (face, pixel) candidate pairs from each face's pixel bounding box, in chunks.
    """
    face_id = np.full(height * width, -1, dtype=np.int64)
    zbuf = np.full(height * width, np.inf)
    bary = np.zeros((height * width, 3))
    if len(faces) == 0:
        return face_id.reshape(height, width), bary.reshape(height, width, 3), zbuf.reshape(height, width)
    p = screen[faces]  # (m,3,2)
    area2 = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 1, 1] - p[:, 0, 1]) * (
        p[:, 2, 0] - p[:, 0, 0]
    )
    x0 = np.clip(np.ceil(p[..., 0].min(1) - 0.5), 0, width).astype(np.int64)
    x1 = np.clip(np.floor(p[..., 0].max(1) - 0.5), -1, width - 1).astype(np.int64)
    y0 = np.clip(np.ceil(p[..., 1].min(1) - 0.5), 0, height).astype(np.int64)
    y1 = np.clip(np.floor(p[..., 1].max(1) - 0.5), -1, height - 1).astype(np.int64)
    w, h = x1 - x0 + 1, y1 - y0 + 1
    keep = np.flatnonzero((w > 0) & (h > 0) & (np.abs(area2) > 1e-12))
    counts = w[keep] * h[keep]
    ends = np.cumsum(counts)
    chunk_of = (ends - 1) // _CHUNK_CANDIDATES
    bounds = np.searchsorted(chunk_of, np.arange(chunk_of[-1] + 2 if len(chunk_of) else 1))
    for a, b in zip(bounds[:-1], bounds[1:]):  # loop over chunks of faces
        if a == b:
            continue
        fids = keep[a:b]
        # Scanline spans: for every (face, pixel row) pair, the x-range where the row's centre line
        # crosses the triangle; only those pixels become candidates (thin CAD fan triangles have
        # huge, nearly empty bounding boxes).
        rf = np.repeat(fids, h[fids])
        py_row = y0[rf] + np.arange(len(rf)) - np.repeat(np.cumsum(h[fids]) - h[fids], h[fids])
        yc = py_row + 0.5
        tri = p[rf]
        xa, ya = tri[..., 0], tri[..., 1]  # (r,3): edge k runs from vertex k to vertex k+1
        xb, yb = np.roll(xa, -1, axis=1), np.roll(ya, -1, axis=1)
        dy = yb - ya
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (yc[:, None] - ya) / dy
        crosses = (dy != 0) & (t >= -1e-9) & (t <= 1 + 1e-9)
        xs = np.where(crosses, xa + np.clip(t, 0, 1) * (xb - xa), np.nan)
        valid = crosses.any(1)
        xs_lo = np.where(crosses, xs, np.inf).min(1)
        xs_hi = np.where(crosses, xs, -np.inf).max(1)
        sx0 = np.clip(np.ceil(xs_lo[valid] - 0.5), x0[rf[valid]], width).astype(np.int64)
        sx1 = np.clip(np.floor(xs_hi[valid] - 0.5), -1, x1[rf[valid]]).astype(np.int64)
        cnt = np.maximum(sx1 - sx0 + 1, 0)
        rf, py_row = rf[valid], py_row[valid]
        f = np.repeat(rf, cnt)
        py = np.repeat(py_row, cnt)
        px = np.repeat(sx0, cnt) + np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        qx, qy = px + 0.5, py + 0.5
        tri = p[f]
        inv = 1.0 / area2[f]
        # Edge functions: weight of vertex k is the signed area of the sub-triangle opposite to it.
        l0 = ((tri[:, 2, 0] - tri[:, 1, 0]) * (qy - tri[:, 1, 1]) - (tri[:, 2, 1] - tri[:, 1, 1]) * (qx - tri[:, 1, 0])) * inv
        l1 = ((tri[:, 0, 0] - tri[:, 2, 0]) * (qy - tri[:, 2, 1]) - (tri[:, 0, 1] - tri[:, 2, 1]) * (qx - tri[:, 2, 0])) * inv
        l2 = 1.0 - l0 - l1
        inside = (l0 >= -1e-9) & (l1 >= -1e-9) & (l2 >= -1e-9)
        if not inside.any():
            continue
        f, l0, l1, l2 = f[inside], l0[inside], l1[inside], l2[inside]
        pid = py[inside] * width + px[inside]
        dz = depth[faces[f]]
        z = l0 * dz[:, 0] + l1 * dz[:, 1] + l2 * dz[:, 2]
        # Depth test without sorting: unbuffered per-pixel minimum, then the candidates that reach
        # it win (exact ties are interchangeable: same depth, either face).
        np.minimum.at(zbuf, pid, z)
        sel = np.flatnonzero(z <= zbuf[pid])
        face_id[pid[sel]] = f[sel]
        bary[pid[sel]] = np.stack([l0[sel], l1[sel], l2[sel]], axis=1)
    return face_id.reshape(height, width), bary.reshape(height, width, 3), zbuf.reshape(height, width)


def face_subset(vertices, faces, max_faces: int, seed: int = 0):
    """A seeded random subset of at most ``max_faces`` faces, with unused vertices dropped."""
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) <= max_faces:
        return np.asarray(vertices), faces
    keep = np.sort(np.random.default_rng(seed).choice(len(faces), max_faces, replace=False))
    return drop_unreferenced_vertices(np.asarray(vertices), faces[keep])


def render_mesh(
    vertices,
    faces,
    colors=None,
    size: tuple[int, int] = (256, 256),
    *,
    bounds=None,
    view: tuple[float, float] = DEFAULT_VIEW,
    base_color=BASE_COLOR,
    outline: bool = True,
    up: str = "y",
) -> bytes:
    """PNG bytes of a shaded triangle mesh, rendered headless on the CPU.

    vertices (n,3) float, faces (m,3) int (canonical frame). colors: None (``base_color``), (3,) RGB,
    (n,3) per-vertex or (m,3) per-face RGB in [0,1] (or 0..255). size = (width, height) in pixels.
    bounds: ((3,) lo, (3,) hi) box that fixes the framing (pass the GT's box to line up a shape's
    renders); default: the mesh's own box. view = (azimuth, elevation) degrees about the ``up`` axis
    ('x', 'y' or 'z': kept up in the image). An empty mesh (or one with no finite triangle) gives a
    blank image of the same size.
    """
    V, F, width, height = _checked(vertices, faces, size)
    mode, color_values = _resolve_colors(colors, len(V), len(F), np.asarray(base_color, dtype=float))
    frame = _Frame(V, F, width, height, bounds, view, up)
    return _encode_png(frame.shade(mode, color_values, outline))


def render_mesh_and_error(vertices, faces, gt_vertices, gt_faces, vmax: float,
                          size: tuple[int, int] = (256, 256), *, bounds=None,
                          view: tuple[float, float] = DEFAULT_VIEW, base_color=BASE_COLOR,
                          outline: bool = True, up: str = "y") -> tuple[bytes, bytes]:
    """PNG bytes of a mesh shaded in ``base_color`` and of the same view coloured by each vertex's
    distance to the GT mesh (:func:`error_colors` of :func:`distances_to_mesh`, ramp up to ``vmax``).

    The same two images as ``render_mesh(vertices, faces, ...)`` and ``render_mesh(vertices, faces,
    colors=error_colors(distances_to_mesh(vertices, gt_vertices, gt_faces), vmax), ...)``, from one
    rasterisation, and with distances computed only for the vertices of faces that cover a pixel
    (the others cannot colour one). Arguments as :func:`render_mesh`.
    """
    V, F, width, height = _checked(vertices, faces, size)
    frame = _Frame(V, F, width, height, bounds, view, up)
    shaded = _encode_png(frame.shade("uniform", np.asarray(base_color, dtype=float), outline))
    distances = np.full(len(V), np.nan)
    seen = frame.visible_vertices()
    distances[seen] = distances_to_mesh(V[seen], gt_vertices, gt_faces)
    return shaded, _encode_png(frame.shade("vertex", error_colors(distances, vmax), outline))


def _checked(vertices, faces, size):
    width, height = int(size[0]), int(size[1])
    if width <= 0 or height <= 0:
        raise ValueError(f"size must be positive (width, height), got {size}")
    V = np.asarray(vertices, dtype=float).reshape(-1, 3)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(F) and (F.min() < 0 or F.max() >= len(V)):
        raise ValueError(f"faces index vertices outside [0, {len(V)})")
    return V, F, width, height


class _Frame:
    """One rasterisation of a mesh (its finite faces) through the camera, supersampled: which face
    and barycentric weights cover each pixel, and its depth; :meth:`shade` colours it."""

    def __init__(self, V, F, width, height, bounds, view, up="y"):
        self.width, self.height = width, height
        finite_faces = np.isfinite(V).all(1)[F].all(1) if len(F) else np.zeros(0, bool)
        self.empty = not finite_faces.any()
        if self.empty:
            return
        if bounds is None:
            used = V[F[finite_faces]].reshape(-1, 3)
            lo, hi = used.min(0), used.max(0)
        else:
            lo, hi = (np.asarray(b, dtype=float).reshape(3) for b in bounds)
        R = camera_rotation(*view, up=up)
        corners = _box_corners(lo, hi) @ R.T
        c_min, c_max = corners.min(0), corners.max(0)
        centre = (c_min + c_max) / 2.0
        self.extent = max(float((c_max - c_min)[:2].max()), 1e-9)
        W, H = width * _SUPERSAMPLE, height * _SUPERSAMPLE
        scale = 0.9 * min(W, H) / self.extent  # 5% margin on each side
        self.cam = np.where(np.isfinite(V), V, 0.0) @ R.T
        screen = np.stack([(self.cam[:, 0] - centre[0]) * scale + W / 2.0,
                           H / 2.0 - (self.cam[:, 1] - centre[1]) * scale], 1)
        self.F_draw = F[finite_faces]
        self.face_index = np.flatnonzero(finite_faces)
        self.face_id, self.bary, self.zbuf = rasterize(screen, -self.cam[:, 2], self.F_draw, W, H)
        self.covered = self.face_id >= 0

    def visible_vertices(self) -> np.ndarray:
        """Indices of the vertices of every face that covers a pixel."""
        if self.empty:
            return np.zeros(0, dtype=np.int64)
        return np.unique(self.F_draw[np.unique(self.face_id[self.covered])])

    def shade(self, mode: str, color_values: np.ndarray, outline: bool) -> np.ndarray:
        """The (height, width, 3) image in [0, 1] with ``(mode, colors)`` of :func:`_resolve_colors`."""
        if self.empty:
            return np.broadcast_to(BACKGROUND, (self.height, self.width, 3))
        ss = _SUPERSAMPLE
        image = np.broadcast_to(BACKGROUND, (self.height * ss, self.width * ss, 3)).copy()
        covered = self.covered
        fid = self.face_id[covered]
        if fid.size:
            tri = self.cam[self.F_draw[fid]]
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
            lights = _LIGHTS / np.linalg.norm(_LIGHTS, axis=1, keepdims=True)
            ndotl = np.abs(n @ lights.T)  # two-sided
            half = lights[0] + np.array([0.0, 0.0, 1.0])
            half /= np.linalg.norm(half)
            diffuse = _AMBIENT + ndotl @ _LIGHT_WEIGHTS
            specular = _SPECULAR * np.abs(n @ half) ** _SHININESS
            if mode == "uniform":
                albedo = np.broadcast_to(color_values, (fid.size, 3))
            elif mode == "face":
                albedo = color_values[self.face_index[fid]]
            else:
                w = self.bary[covered]
                albedo = np.einsum("pk,pkc->pc", w, color_values[self.F_draw[fid]])
            image[covered] = np.clip(albedo * diffuse[:, None] + specular[:, None], 0.0, 1.0)
            if outline:
                image = _darken_edges(image, covered, self.zbuf, depth_scale=self.extent)
        return image.reshape(self.height, ss, self.width, ss, 3).mean(axis=(1, 3))


def _darken_edges(image, covered, zbuf, depth_scale: float, strength: float = 0.55):
    """Darken silhouette pixels (covered next to background) and depth jumps (> 1.5% of the view
    extent between 4-neighbours of the z-buffer)."""
    z = np.where(covered, zbuf, np.nan)
    edge = np.zeros(covered.shape, bool)
    for axis in (0, 1):  # loop over the 2 image axes
        a = np.take(covered, np.arange(1, covered.shape[axis]), axis=axis)
        b = np.take(covered, np.arange(0, covered.shape[axis] - 1), axis=axis)
        za = np.take(z, np.arange(1, z.shape[axis]), axis=axis)
        zb = np.take(z, np.arange(0, z.shape[axis] - 1), axis=axis)
        jump = (a != b) | (a & b & (np.abs(za - zb) > 0.015 * depth_scale))
        pad_hi = [(0, 0), (0, 0)]
        pad_lo = [(0, 0), (0, 0)]
        pad_hi[axis] = (1, 0)
        pad_lo[axis] = (0, 1)
        edge |= np.pad(jump, pad_hi) | np.pad(jump, pad_lo)
    mark = edge & covered
    image[mark] *= 1.0 - strength
    return image


def distances_to_mesh(points, vertices, faces) -> np.ndarray:
    """Unsigned Euclidean distance (n,) from each point to the triangle mesh (exact, libigl AABB tree);
    units of the inputs (canonical frame). NaN for non-finite points; inf when the mesh has no face."""
    import igl

    P = np.asarray(points, dtype=float).reshape(-1, 3)
    out = np.full(len(P), np.nan)
    if len(faces) == 0:
        out[:] = np.inf
        return out
    finite = np.isfinite(P).all(1)
    if finite.any():
        sq = igl.point_mesh_squared_distance(
            np.ascontiguousarray(P[finite]),
            np.ascontiguousarray(vertices, dtype=float),
            np.ascontiguousarray(faces, dtype=np.int64),
        )[0]
        out[finite] = np.sqrt(np.maximum(sq, 0.0))
    return out


# Error ramp: near-zero error reads as neutral light blue-grey, then yellow, orange, dark red at vmax.
ERROR_STOPS = ((0.0, "#dbe4ee"), (0.25, "#fee391"), (0.55, "#fe9929"), (0.8, "#d7301f"), (1.0, "#7f0000"))


def _hex_rgb(code: str) -> np.ndarray:
    return np.array([int(code[i : i + 2], 16) for i in (1, 3, 5)], dtype=float) / 255.0


def error_colors(distances, vmax: float) -> np.ndarray:
    """(n,3) RGB in [0,1] for distances on the ERROR_STOPS ramp, linear over [0, vmax] and clipped
    above vmax; NaN distances are mid grey."""
    d = np.asarray(distances, dtype=float)
    t = np.clip(d / float(vmax), 0.0, 1.0)
    stops = np.array([s for s, _ in ERROR_STOPS])
    rgb = np.stack([_hex_rgb(c) for _, c in ERROR_STOPS])
    out = np.stack([np.interp(np.nan_to_num(t), stops, rgb[:, k]) for k in range(3)], axis=1)
    out[~np.isfinite(d)] = 0.5
    return out


def error_gradient_css() -> str:
    """The ERROR_STOPS ramp as a CSS linear-gradient (for the HTML colour bar)."""
    return "linear-gradient(to right, " + ", ".join(f"{c} {s * 100:.0f}%" for s, c in ERROR_STOPS) + ")"
