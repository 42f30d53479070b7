"""Anti-aliased rendering of a calibration board by inverse mapping (ray casting), in log intensity.

For each pixel the undistorted viewing ray (precomputed once per camera from the camera model) is
intersected with the board plane z = 0 in the board frame; the board coordinates of the hit decide the
reflectance. The scene is a flat target on a textured wall in the same plane:

* the board: white paper (``white``) with black ink (``black``) circles or AprilTags, and a white
  ``margin`` around the pattern;
* the wall around it: grey (``background``) with a smooth sinusoidal texture, so that the board's edge
  and the surroundings also produce events, as they do in a real room;
* rays that miss the plane (it is behind the camera or seen edge-on) see flat grey;
* seen from behind (from the side the pattern is not printed on) the board is blank backing (``white``, no ink):
  a camera driven around a board on a stand sees its back, never a mirror image of its pattern.

Anti-aliasing is analytic: each ray carries a footprint (the size of its pixel on the board plane,
from depth, focal length and incidence) and circle and rectangle edges are box-filtered over it with a
linear ramp on the signed distance; AprilTag cells are box-filtered separably. ``supersample`` > 1 adds
s x s rays per pixel on top, for very oblique views.

AprilGrid orientation: tag k (row k // cols, column k % cols, Kalibr numbering) occupies
[c p, c p + size] x [r p, r p + size] with p = (1 + spacing) size, printed on the board's +z face with
the marker image's top row at the tag's largest y. Seen from the +z side (board y up in the image) the
tags read correctly; OpenCV's aruco corner 0 (marker top-left) is then the board point (x0, y0 + size).
Seen from the -z side the board is blank, as the back of a real print is. Circle grids are printed on the -z face
(x right, y down as printed, so +z points away from the viewer).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..core.board import Board
from ..core.camera import CameraModel
from ..errors import InputError


@dataclass(frozen=True)
class RenderParams:
    """Scene and rendering parameters. Reflectances are relative to a white of 1; ``illumination`` scales all."""

    white: float = 0.9
    black: float = 0.05
    background: float = 0.35
    background_texture: float = 0.15  # relative amplitude of the wall texture, 0 for a flat wall
    texture_wavelength_m: float = 0.12
    margin_m: float | None = None  # white border around the pattern; None: one square (circles) / half a tag
    illumination: float = 1.0
    log_eps: float = 1e-3  # log(I + eps), as sensors and ESIM do, so black stays finite
    supersample: int = 1  # s x s rays per pixel; 1 is enough with the analytic anti-aliasing
    tag_layout: str = "opencv"  # AprilGrid print: "opencv" (1-bit border, upright) or "kalibr" (2-bit, turned)

    def __post_init__(self) -> None:
        for name in ("white", "black", "background", "illumination", "texture_wavelength_m", "log_eps"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise InputError(f"RenderParams: {name} must be positive, got {v}")
        if not 0 <= self.background_texture < 1:
            raise InputError(f"RenderParams: background_texture must be in [0, 1), got {self.background_texture}")
        if self.margin_m is not None and self.margin_m < 0:
            raise InputError(f"RenderParams: margin_m must be >= 0, got {self.margin_m}")
        if self.tag_layout not in TAG_LAYOUTS:
            raise InputError(f"RenderParams: tag_layout must be one of {TAG_LAYOUTS}, got {self.tag_layout!r}")
        if int(self.supersample) < 1:
            raise InputError(f"RenderParams: supersample must be >= 1, got {self.supersample}")


@lru_cache(maxsize=8)
def _rays_cached(width: int, height: int, K: bytes, dist: bytes, ss: int) -> tuple[np.ndarray, np.ndarray]:
    cam = CameraModel(width, height, np.frombuffer(K).reshape(3, 3), np.frombuffer(dist))
    # Sub-pixel sample offsets centred in each pixel, e.g. ss = 2: -0.25, +0.25.
    off = (np.arange(ss) + 0.5) / ss - 0.5
    v, u = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    uu = (u[:, :, None, None] + off[None, None, None, :]).repeat(ss, axis=2)
    vv = (v[:, :, None, None] + off[None, None, :, None]).repeat(ss, axis=3)
    uv = np.stack([uu.ravel(), vv.ravel()], axis=-1)
    xn = cam.undistort_pixels(uv)
    rays = np.concatenate([xn, np.ones((xn.shape[0], 1))], axis=1)
    # Solid-angle scale of each sample: |d(xn)/d(uv)| from the undistortion, approximated by 1/f / ss.
    pix_angle = np.full(xn.shape[0], 1.0 / (np.sqrt(cam.fx * cam.fy) * ss))
    rays.setflags(write=False)
    pix_angle.setflags(write=False)
    return rays, pix_angle


def camera_rays(camera: CameraModel, supersample: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted rays (n, 3) with z = 1 of every (sub)pixel sample, row-major (y, x, sub_y, sub_x), and the
    angular size of one sample (n,). Cached per camera."""
    return _rays_cached(
        int(camera.width), int(camera.height), camera.K.tobytes(), camera.dist.tobytes(), int(supersample)
    )


TAG_LAYOUTS = ("opencv", "kalibr")


@lru_cache(maxsize=4)
def _tag36h11_bits(n: int, layout: str = "opencv") -> np.ndarray:
    """(n, m, m) float32 reflectance masks of tag36h11 ids 0..n-1 incl. the black border: 1 white, 0 black.

    ``"opencv"``: OpenCV's marker images upright with a 1-bit border (m = 8). ``"kalibr"``: as Kalibr prints
    AprilGrids, a 2-bit border (m = 10) and each code turned by 180 degrees relative to OpenCV's image.
    """
    import cv2

    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    if n > d.bytesList.shape[0]:
        raise InputError(f"aprilgrid: {n} tags exceed the {d.bytesList.shape[0]} ids of tag36h11")
    border = 1 if layout == "opencv" else 2
    out = np.stack([cv2.aruco.generateImageMarker(d, k, 6 + 2 * border, borderBits=border) for k in range(n)])
    if layout == "kalibr":
        out = out[:, ::-1, ::-1]
    return np.ascontiguousarray(out > 127).astype(np.float32)


def _ramp(sd: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Box-filtered coverage of the region {signed distance < 0} by a footprint of width w."""
    return np.clip(0.5 - sd / w, 0.0, 1.0)


class BoardRenderer:
    """Renders one board for one camera repeatedly (the rays are computed once)."""

    def __init__(self, camera: CameraModel, board: Board, params: RenderParams | None = None):
        self.camera = camera
        self.board = board
        self.params = params or RenderParams()
        ss = int(self.params.supersample)
        self.ss = ss
        self.rays, self.pix_angle = camera_rays(camera, ss)
        self._rx = np.ascontiguousarray(self.rays[:, 0], dtype=np.float32)
        self._ry = np.ascontiguousarray(self.rays[:, 1], dtype=np.float32)
        self._ray_norm = np.linalg.norm(self.rays, axis=1).astype(np.float32)
        self._w_scale = (self._ray_norm**1.5 * self.pix_angle).astype(np.float32)
        p = board.points
        if board.pattern == "asymmetric_circles":
            r = 0.5 * board.circle_diameter
            lo, hi = p[:, :2].min(axis=0) - r, p[:, :2].max(axis=0) + r
            margin = board.square_size if self.params.margin_m is None else self.params.margin_m
        else:
            lo, hi = p[:, :2].min(axis=0), p[:, :2].max(axis=0)
            margin = 0.5 * board.tag_size if self.params.margin_m is None else self.params.margin_m
            self.tag_bits = _tag36h11_bits(board.rows * board.cols, self.params.tag_layout)
        self.board_lo = lo - margin
        self.board_hi = hi + margin

    # -- reflectance of board-plane points ------------------------------------------------------------
    def _circles_ink(self, X: np.ndarray, Y: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Ink coverage (0..1) of asymmetric-grid circles."""
        b = self.board
        s, r = b.square_size, 0.5 * b.circle_diameter
        # A point inside circle row i has |Y/s - i| < r/s < 1/sqrt(2), so rows floor(Y/s) and floor(Y/s) + 1
        # are the only candidates; in a row the nearest column follows from rounding.
        i0 = np.floor(Y / s)
        d2 = None
        for di in (0.0, 1.0):
            i = np.clip(i0 + di, 0, b.rows - 1)
            odd = i - 2.0 * np.floor(0.5 * i)  # i mod 2; np.mod is slow on floats
            j = np.clip(np.rint((X / s - odd) * 0.5), 0, b.cols - 1)
            dx = X - (2.0 * j + odd) * s
            dy = Y - i * s
            e = dx * dx + dy * dy
            d2 = e if d2 is None else np.minimum(d2, e)
        return _ramp(np.sqrt(d2) - r, w)

    def _tags_ink(self, X: np.ndarray, Y: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Ink coverage (0..1) of AprilGrid tags, box-filtered separably over the m x m cells of each tag."""
        b = self.board
        size = b.tag_size
        pitch = (1.0 + b.tag_spacing) * size
        m = self.tag_bits.shape[1]
        cell = size / m
        c = np.floor(X / pitch)
        r = np.floor(Y / pitch)
        u = (X - c * pitch) / cell  # tag-local cell coordinates, 0..m inside the tag
        v = (Y - r * pitch) / cell
        in_grid = (c >= 0) & (c < b.cols) & (r >= 0) & (r < b.rows)
        tag = np.where(in_grid, r * b.cols + c, 0).astype(np.intp)
        hw = np.minimum(0.5 * w / cell, 0.5)  # half footprint in cells, capped so at most two cells overlap

        def split(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            lo = np.floor(q - hw)
            w_hi = np.clip((q + hw - (lo + 1.0)) / (2.0 * hw), 0.0, 1.0)
            return lo.astype(np.intp), lo.astype(np.intp) + 1, w_hi

        ua, ub, wu = split(u)
        va, vb, wv = split(v)
        bits = self.tag_bits

        def white(ci: np.ndarray, ri: np.ndarray) -> np.ndarray:
            inside = in_grid & (ci >= 0) & (ci < m) & (ri >= 0) & (ri < m)
            # Marker image row 0 is the tag's top edge, at the largest board y.
            val = bits[tag, np.clip(m - 1 - ri, 0, m - 1), np.clip(ci, 0, m - 1)]
            return np.where(inside, val, 1.0)

        refl = (1 - wv) * ((1 - wu) * white(ua, va) + wu * white(ub, va)) + wv * (
            (1 - wu) * white(ua, vb) + wu * white(ub, vb)
        )
        return 1.0 - refl

    def _wall(self, X: np.ndarray, Y: np.ndarray, w: np.ndarray) -> np.ndarray:
        p = self.params
        if p.background_texture == 0:
            return np.full(X.shape, p.background, dtype=X.dtype)
        k = 2 * np.pi / p.texture_wavelength_m
        # Two plane waves in different directions: texture with edges in every direction, but no round
        # dark spots that a blob detector could take for circles of the board.
        tex = (np.sin(k * (0.8 * X + 0.6 * Y) + 0.3) + 0.5 * np.sin(0.37 * k * (0.28 * X - 0.96 * Y) + 1.1)) / 1.5
        # Fade the texture where a pixel covers a good part of a wavelength (distant, grazing), instead of aliasing.
        # A box of width w has variance w^2 / 12; a Gaussian of that variance attenuates a sinusoid like this.
        fade = np.exp((k * w) ** 2 * np.float32(-1.0 / 24.0))
        return p.background * (1.0 + p.background_texture * tex * fade)

    def seen_from_back(self, T_board_cam: np.ndarray) -> bool:
        """True when the camera (pose ``T_board_cam``) is on the side of the board its pattern is not printed on:
        circle grids are printed on the -z face, AprilGrids on the +z face."""
        z = float(np.asarray(T_board_cam)[2, 3])  # the camera's position along the board's normal
        return z > 0 if self.board.pattern == "asymmetric_circles" else z < 0

    def reflectance(self, X: np.ndarray, Y: np.ndarray, w: np.ndarray, back: bool = False) -> np.ndarray:
        """Reflectance of board-plane points (X, Y) seen with footprint w (all same shape); ``back``: the board is
        seen from behind (blank backing, no pattern)."""
        p = self.params
        centre = (0.5 * (self.board_lo + self.board_hi)).astype(X.dtype)
        half = (0.5 * (self.board_hi - self.board_lo)).astype(X.dtype)
        sd_rect = np.maximum(np.abs(X - centre[0]) - half[0], np.abs(Y - centre[1]) - half[1])
        on_board = _ramp(sd_rect, w)
        # The wall is computed everywhere (cheaper than gathering the usually large part of the image that
        # sees it); the pattern only where the board is seen.
        out = self._wall(X, Y, w)
        ib = np.flatnonzero(on_board)
        if ib.size:
            out *= 1.0 - on_board
            if back:
                out[ib] += on_board[ib] * p.white
            else:
                ink = self._ink(X[ib], Y[ib], w[ib])
                out[ib] += on_board[ib] * (p.white + (p.black - p.white) * ink)
        return out

    def _ink(self, X: np.ndarray, Y: np.ndarray, w: np.ndarray) -> np.ndarray:
        if self.board.pattern == "asymmetric_circles":
            return self._circles_ink(X, Y, w)
        return self._tags_ink(X, Y, w)

    # -- rendering -------------------------------------------------------------------------------------
    def intensity(self, T_board_cam: np.ndarray) -> np.ndarray:
        """Irradiance image (height, width), float32, white paper facing the camera = ``white * illumination``."""
        T = np.asarray(T_board_cam, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError("render: T_board_cam must be a finite 4 x 4 transform")
        R = T[:3, :3].astype(np.float32)
        o = T[:3, 3].astype(np.float32)
        rx, ry = self._rx, self._ry
        # Ray directions in the board frame, written out: numpy's matmul is slow for (n, 3) @ (3, 3).
        dz = R[2, 0] * rx + R[2, 1] * ry + R[2, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = -o[2] / dz
        hit = (s > 0) & np.isfinite(s)
        all_hit = bool(hit.all())
        if not all_hit:
            s[~hit] = 0.0
        X = (R[0, 0] * rx + R[0, 1] * ry + R[0, 2]) * s + o[0]
        Y = (R[1, 0] * rx + R[1, 1] * ry + R[1, 2]) * s + o[1]
        # Footprint on the plane: range * angular size, stretched by 1/sqrt(cos(incidence)) (the geometric
        # mean of the two axes). |d| = |ray| since R is a rotation; cos(incidence) = |dz| / |ray|.
        np.abs(dz, out=dz)
        np.maximum(dz, self._ray_norm * np.float32(1e-3), out=dz)
        w = s * self._w_scale / np.sqrt(dz)
        np.maximum(w, np.float32(1e-9), out=w)
        refl = self.reflectance(X, Y, w, back=self.seen_from_back(T))
        if not all_hit:
            refl[~hit] = self.params.background
        img = refl.reshape(self.camera.height, self.camera.width, self.ss * self.ss)
        img = img.mean(axis=2) if self.ss > 1 else img[:, :, 0]
        if self.params.illumination != 1.0:
            img = img * np.float32(self.params.illumination)
        return img

    def log_intensity(self, T_board_cam: np.ndarray) -> np.ndarray:
        return np.log(self.intensity(T_board_cam) + np.float32(self.params.log_eps))


def render_log_intensity(
    T_board_cam: np.ndarray, camera: CameraModel, board: Board, params: RenderParams | None = None
) -> np.ndarray:
    """Log intensity log(I + eps) (height, width) float32 of the board seen from pose T_board_cam."""
    return BoardRenderer(camera, board, params).log_intensity(T_board_cam)


def render_intensity_u8(
    T_board_cam: np.ndarray, camera: CameraModel, board: Board, params: RenderParams | None = None
) -> np.ndarray:
    """8-bit grey image (white paper ~ 255 * white / 1, black ink dark) for frame-based detector tests."""
    r = BoardRenderer(camera, board, params)
    return np.clip(r.intensity(T_board_cam) * 255.0 + 0.5, 0, 255).astype(np.uint8)
