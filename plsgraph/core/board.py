"""Calibration target definitions (YAML files; bundled ones in plsgraph/data/boards/) and their 3-D point layouts.

Asymmetric circle grid, OpenCV convention: ``cols`` circles per row (patternSize width), ``rows``
rows; circle (row i, col j) sits at ((2 j + i mod 2) s, i s, 0) with s = ``square_size``. Points are
ordered row-major, point index = i * cols + j, the order cv2.findCirclesGrid returns.

Kalibr's target files are read as well: ``aprilgrid`` as it is, ``circlegrid`` with ``asymmetricGrid: True``
(Kalibr places its circles the same way, ``spacingMeters`` being s) and a ``circle_diameter`` added, which Kalibr's
file does not hold. A key that none of these formats has is refused, so that a misspelt key does not silently
leave its default in place.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from ..errors import InputError
from .resources import bundled_file, bundled_names, read_yaml_mapping

PATTERNS = ("asymmetric_circles", "aprilgrid")


#: More points per side than any printable target has (a typo such as 1000000 would exhaust the memory).
MAX_SIDE = 100

#: Largest circle spacing / diameter (m) and AprilGrid tag (m) taken as metres: beyond, the file's lengths are
#: almost surely in centimetres or millimetres (a 4 x 11 grid at 0.3 m spacing is already 2.1 x 3.3 m). The tag's
#: limit admits the bundled board whose tag size is unknown and given as 1 (poses in tag sizes).
MAX_SPACING_M = 0.3
MAX_TAG_M = 1.0

#: The keys a board file may hold, per pattern (plsgraph's own and Kalibr's), and keys any file may carry.
_KEYS = {
    "asymmetric_circles": {"cols", "rows", "square_size", "circle_diameter"},
    "aprilgrid": {"cols", "rows", "tag_size", "tag_spacing", "tag_family", "tag_border_bits",
                  "tagCols", "tagRows", "tagSize", "tagSpacing", "codeOffset"},
}
_ANY_KEYS = {"pattern", "target_type", "name", "description", "comment", "notes"}
_KALIBR_CIRCLES = {"targetCols", "targetRows", "spacingMeters", "asymmetricGrid", "circle_diameter"}


@dataclass(frozen=True)
class Board:
    """A planar target. ``points`` (N, 3) are the measurable points in the board frame (z = 0)."""

    pattern: str
    cols: int
    rows: int
    square_size: float = 0.0
    circle_diameter: float = 0.0
    tag_size: float = 0.0
    tag_spacing: float = 0.0
    tag_family: str = "tag36h11"
    tag_border_bits: int = 2  # black border around each tag's code, in cells: Kalibr prints 2, OpenCV's default 1
    name: str = ""

    def __post_init__(self) -> None:
        if self.pattern not in PATTERNS:
            raise InputError(f"board: unknown pattern {self.pattern!r}; use one of {', '.join(PATTERNS)}")
        for k in ("cols", "rows"):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, int | np.integer):
                raise InputError(f"board: {k} has the wrong type: it must be a whole number, got {v!r}")
        if self.cols < 1 or self.rows < 1:
            raise InputError(f"board: cols and rows must be positive, got {self.cols} x {self.rows}")
        if self.cols > MAX_SIDE or self.rows > MAX_SIDE:
            raise InputError(f"board: {self.cols} x {self.rows} points is not a printable target (at most {MAX_SIDE} "
                             "per side); check cols and rows in the board file")
        for k in ("square_size", "circle_diameter", "tag_size", "tag_spacing"):
            if not np.isfinite(getattr(self, k)):
                raise InputError(f"board: {k} must be a finite number of metres, got {getattr(self, k)!r}")
        if self.pattern == "asymmetric_circles":
            if self.square_size <= 0 or self.circle_diameter <= 0:
                raise InputError("board: asymmetric_circles needs positive square_size and circle_diameter")
            if max(self.square_size, self.circle_diameter) > MAX_SPACING_M:
                raise InputError(
                    f"board: square_size {self.square_size:g} and circle_diameter {self.circle_diameter:g} are "
                    f"read as metres, which makes circles {2 * self.square_size:g} m apart; a board's lengths are "
                    f"in metres (0.05, not 5 cm or 50 mm): check the board file"
                )
            if self.circle_diameter >= np.sqrt(2) * self.square_size:
                raise InputError(
                    f"board: circle_diameter {self.circle_diameter} m makes neighbouring circles touch "
                    f"(they are {np.sqrt(2) * self.square_size:.4f} m apart); check square_size"
                )
        elif self.tag_size <= 0 or self.tag_spacing < 0:
            raise InputError("board: aprilgrid needs positive tag_size and non-negative tag_spacing")
        elif self.tag_size > MAX_TAG_M:
            raise InputError(f"board: tag_size {self.tag_size:g} is read as metres; a board's lengths are in metres "
                             "(0.088, not 8.8 cm or 88 mm): check the board file")
        elif (isinstance(self.tag_border_bits, bool) or not isinstance(self.tag_border_bits, int | np.integer)
              or self.tag_border_bits not in (1, 2, 3)):
            raise InputError(f"board: tag_border_bits must be 1, 2 or 3 (cells of black border around each tag; "
                             f"Kalibr's AprilGrids have 2), got {self.tag_border_bits!r}")

    @property
    def pattern_size(self) -> tuple[int, int]:
        """(cols, rows) as OpenCV's patternSize."""
        return (self.cols, self.rows)

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def points(self) -> np.ndarray:
        """The points (n, 3) in the board frame (metres, z = 0), a fresh copy for each caller."""
        return self._points.copy()

    @cached_property
    def _points(self) -> np.ndarray:  # the detector asks thousands of times per recording
        if self.pattern == "asymmetric_circles":
            i, j = np.divmod(np.arange(self.rows * self.cols), self.cols)
            s = self.square_size
            return np.stack([(2 * j + i % 2) * s, i * s, np.zeros(i.size)], axis=-1)
        return aprilgrid_points(self.cols, self.rows, self.tag_size, self.tag_spacing)

    @property
    def extent(self) -> tuple[float, float]:
        """Width and height (m) of the region the points and circles cover."""
        p = self.points
        pad = self.circle_diameter if self.pattern == "asymmetric_circles" else 0.0
        return float(np.ptp(p[:, 0]) + pad), float(np.ptp(p[:, 1]) + pad)

    @classmethod
    def from_dict(cls, d: dict, name: str = "") -> Board:
        if not isinstance(d, dict) or "pattern" not in d:
            raise InputError("board: definition must be a mapping with a 'pattern' field")
        try:
            return cls._from_dict(d, name)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(f"board {name or ''}: a field has the wrong type ({exc})") from exc

    @classmethod
    def _from_dict(cls, d: dict, name: str) -> Board:
        pattern = d["pattern"]
        if pattern not in PATTERNS:  # before the fields: another pattern's fields are not ours to ask for
            raise InputError(f"board: unknown pattern {pattern!r}; use one of {', '.join(PATTERNS)}")
        unknown = sorted(str(k) for k in d if k not in _KEYS[pattern] | _ANY_KEYS)
        if unknown:
            raise InputError(
                f"board: unknown key{'s' if len(unknown) > 1 else ''} {', '.join(unknown)} for pattern {pattern}; "
                f"a board file of this pattern takes {', '.join(sorted(_KEYS[pattern]))} (lengths in metres)")
        for k in ("cols", "rows", "tagCols", "tagRows"):
            v = d.get(k)
            if v is not None and (isinstance(v, bool) or not (isinstance(v, int) or (isinstance(v, float)
                                                                                    and v.is_integer()))):
                raise InputError(f"board: {k} has the wrong type: it must be a whole number, got {v!r}")
        if pattern == "aprilgrid":
            # Kalibr's keys (tagCols, tagRows, tagSize, tagSpacing) are accepted as they are.
            return cls(
                pattern="aprilgrid",
                cols=int(d.get("cols", d.get("tagCols", 0))),
                rows=int(d.get("rows", d.get("tagRows", 0))),
                tag_size=float(d.get("tag_size", d.get("tagSize", 0.0))),
                tag_spacing=float(d.get("tag_spacing", d.get("tagSpacing", 0.0))),
                tag_family=str(d.get("tag_family", "tag36h11")),
                tag_border_bits=_whole(d.get("tag_border_bits", 2), "tag_border_bits"),
                name=name,
            )
        try:
            return cls(
                pattern=str(pattern),
                cols=int(d["cols"]),
                rows=int(d["rows"]),
                square_size=float(d["square_size"]),
                circle_diameter=float(d["circle_diameter"]),
                name=name,
            )
        except KeyError as exc:
            raise InputError(f"board: missing field {exc} (needs cols, rows, square_size, circle_diameter)") from exc

    @classmethod
    def from_yaml(cls, path: str | Path) -> Board:
        path = Path(path)
        d = read_yaml_mapping(path, "board file")
        if d.get("target_type") == "aprilgrid":  # a Kalibr target file
            d = dict(d, pattern="aprilgrid")
        elif d.get("target_type") == "circlegrid":
            d = _from_kalibr_circlegrid(d)
        elif "target_type" in d and "pattern" not in d:
            raise InputError(f"board file {path}: Kalibr target_type {d['target_type']!r} is not a target plsgraph "
                             "detects; it takes an asymmetric circle grid or an AprilGrid")
        return cls.from_dict(d, name=path.stem)


def _from_kalibr_circlegrid(d: dict) -> dict:
    """A Kalibr ``circlegrid`` target file as plsgraph's asymmetric_circles keys (the same point layout)."""
    unknown = sorted(str(k) for k in d if k not in _KALIBR_CIRCLES | _ANY_KEYS)
    if unknown:
        raise InputError(f"board: unknown key{'s' if len(unknown) > 1 else ''} {', '.join(unknown)} in a Kalibr "
                         f"circlegrid file; it takes {', '.join(sorted(_KALIBR_CIRCLES))}")
    if d.get("asymmetricGrid") is not True:
        raise InputError("board: a symmetric circle grid (Kalibr circlegrid without asymmetricGrid: True) has no "
                         "unique orientation; plsgraph detects asymmetric circle grids only")
    missing = [k for k in ("targetCols", "targetRows", "spacingMeters") if k not in d]
    if missing:
        raise InputError(f"board: the Kalibr circlegrid file lacks {', '.join(missing)}")
    if "circle_diameter" not in d:
        raise InputError("board: a Kalibr circlegrid file does not give the circles' size; add "
                         "circle_diameter: <metres> (measured on the print) to it")
    return {"pattern": "asymmetric_circles", "cols": d["targetCols"], "rows": d["targetRows"],
            "square_size": d["spacingMeters"], "circle_diameter": d["circle_diameter"]}


def _whole(v: object, key: str) -> int:
    if isinstance(v, bool) or not (isinstance(v, int) or (isinstance(v, float) and v.is_integer())):
        raise InputError(f"board: {key} has the wrong type: it must be a whole number, got {v!r}")
    return int(v)


def aprilgrid_points(cols: int, rows: int, tag_size: float, spacing_ratio: float) -> np.ndarray:
    """Kalibr AprilGrid corner positions, (4 * rows * cols, 3).

    Kalibr numbers the corners on a (2 rows) x (2 cols) grid, row-major from the board origin
    (corner of tag 0): point (r, c) lies at x = (c // 2) (1 + spacing) size + (c % 2) size, same for y.
    Tag id k (row k // cols, column k % cols) owns grid points (2 r, 2 c), (2 r, 2 c + 1),
    (2 r + 1, 2 c + 1), (2 r + 1, 2 c): its corners in counter-clockwise order from the origin side.
    """
    nr, nc = 2 * rows, 2 * cols
    r, c = np.divmod(np.arange(nr * nc), nc)
    pitch = (1.0 + spacing_ratio) * tag_size
    x = (c // 2) * pitch + (c % 2) * tag_size
    y = (r // 2) * pitch + (r % 2) * tag_size
    return np.stack([x, y, np.zeros(x.size)], axis=-1)


def load_board(name_or_path: str | Path) -> Board:
    """A board from a YAML path, or by bundled name (e.g. ``acircles_4x11``)."""
    p = Path(name_or_path)
    if p.is_file():
        return Board.from_yaml(p)
    bundled = bundled_file("boards", str(p))
    if bundled is not None:
        return Board.from_yaml(bundled)
    have = ", ".join(bundled_names("boards"))
    raise InputError(f"board {name_or_path!r} not found; give a YAML path or one of: {have}")
