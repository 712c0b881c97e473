"""ChArUco boards: OpenCV finds and identifies the corners, tofmetry refines and checks them.

A ChArUco board is a checkerboard whose white squares carry ArUco markers: every corner has an
id, so a board partly outside the image (or partly hidden) still gives its corners with their
board coordinates, and views can push the board into the image corners where a plain
checkerboard, which must be seen whole, cannot reach.

1. **Find** (:func:`detect_charuco`): ``cv2.aruco.CharucoDetector.detectBoard`` on the robust
   8-bit stretch of the IR image (:func:`~tofmetry.calibrate._corners.normalize_ir`), then on a
   gamma-0.5 stretch; the try with more corners wins.
2. **Refine**: the X-junction fit of :mod:`._corner_fit` on the image's own intensities, in a disc
   of 0.7 x the local cell height as for the checkerboard, with the pixels on the two markers
   next to each corner masked out (the mask is point-symmetric about the corner, as the model
   is). The local board-to-image homography comes from the detected corners within two cells.
   Corners whose fit is not accepted keep OpenCV's corner (``cornerSubPix`` inside the detector).
3. **Check**: every corner against a polynomial through its grid neighbours
   (:func:`~tofmetry.calibrate._corners.grid_consistency_ids`); disagreeing corners are dropped
   (a partial view stays usable without them).

Board frame (OpenCV's): origin at the outer top-left corner of the squares, x along the
``squares_x`` columns, y down the rows, z into the board; corner id ``k`` is inner corner
``(k % (squares_x - 1), k // (squares_x - 1))`` at ``((i + 1) s, (j + 1) s, 0)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from tofmetry.calibrate._corner_fit import _xjunction_fit
from tofmetry.calibrate._corners import FIT_RADIUS_FRAC, FIT_RADIUS_MAX_PX, FIT_RADIUS_MIN_PX, GRID_OUTLIER_PX, \
    grid_consistency_ids, gray_float, normalize_ir
from tofmetry.errors import InputError


@dataclass(frozen=True)
class CharucoBoard:
    """A ChArUco board design (OpenCV's ``cv2.aruco.CharucoBoard``, default pattern).

    Attributes
    ----------
    squares_x, squares_y : number of squares along x and y (inner corners: one less each)
    square_mm, marker_mm : side of a square and of a marker [mm]
    dictionary : OpenCV predefined dictionary name (``DICT_4X4_50`` ...)
    """

    squares_x: int = 9
    squares_y: int = 7
    square_mm: float = 80.0
    marker_mm: float = 56.0
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self):
        if int(self.squares_x) < 3 or int(self.squares_y) < 3:
            raise InputError(f"ChArUco board: needs >= 3x3 squares, found {self.squares_x}x{self.squares_y}")
        if not 0 < self.marker_mm < self.square_mm:
            raise InputError(f"ChArUco board: needs 0 < marker_mm < square_mm, found marker {self.marker_mm} mm, "
                             f"square {self.square_mm} mm")
        if not hasattr(cv2.aruco, str(self.dictionary)) or not str(self.dictionary).startswith("DICT_"):
            raise InputError(f"ChArUco board: unknown ArUco dictionary {self.dictionary!r} (expected an OpenCV name "
                             "such as DICT_4X4_50)")
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        need = (self.squares_x * self.squares_y) // 2
        if d.bytesList.shape[0] < need:
            raise InputError(f"ChArUco board: {self.dictionary} has {d.bytesList.shape[0]} markers, the "
                             f"{self.squares_x}x{self.squares_y} board needs {need}")

    @property
    def inner(self) -> tuple[int, int]:
        """(cols, rows) inner corners."""
        return int(self.squares_x) - 1, int(self.squares_y) - 1

    @property
    def n_corners(self) -> int:
        c, r = self.inner
        return c * r

    def cv(self):
        """The ``cv2.aruco.CharucoBoard`` (lengths in mm)."""
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((int(self.squares_x), int(self.squares_y)), float(self.square_mm),
                                      float(self.marker_mm), d)

    def object_points(self, ids: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) float64 board coordinates [mm] of the corners ``ids`` (all when None)."""
        c, r = self.inner
        k = np.arange(c * r) if ids is None else np.asarray(ids, np.int64).ravel()
        if k.size and (k.min() < 0 or k.max() >= c * r):
            raise InputError(f"ChArUco board: corner ids must be in 0..{c * r - 1}, found {k.min()}..{k.max()}")
        s = float(self.square_mm)
        return np.column_stack([(k % c + 1) * s, (k // c + 1) * s, np.zeros(k.size)]).astype(np.float64)

    def to_dict(self) -> dict:
        return {"type": "charuco", "squares_x": int(self.squares_x), "squares_y": int(self.squares_y),
                "square_mm": float(self.square_mm), "marker_mm": float(self.marker_mm),
                "dictionary": str(self.dictionary)}

    @classmethod
    def from_dict(cls, d: dict) -> "CharucoBoard":
        try:
            return cls(int(d["squares_x"]), int(d["squares_y"]), float(d["square_mm"]), float(d["marker_mm"]),
                       str(d.get("dictionary", "DICT_4X4_50")))
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"ChArUco board: expected squares_x, squares_y, square_mm, marker_mm[, dictionary], "
                             f"found {d!r} ({e})") from None


@dataclass(eq=False)
class CharucoDetection:
    """Result of :func:`detect_charuco`.

    Attributes
    ----------
    ids : (N,) int, corner ids (board order)
    corners : (N, 2) float64 [px], refined
    object_points : (N, 3) float64 [mm], the corners' board coordinates
    opencv_corners : (N, 2) float64 [px], the detector's own corners (``cornerSubPix``)
    model_ok : (N,) bool, refined by the X-junction fit (else OpenCV's corner is kept)
    std_px : (N,) float64, the fit's own standard uncertainty [px] (NaN where not fitted)
    n_markers : markers decoded
    dropped : ids removed because they disagree with their grid neighbours
    stretch : ``"percentile"`` or ``"gamma"``: the 8-bit stretch the detector succeeded on
    """

    ids: np.ndarray
    corners: np.ndarray
    object_points: np.ndarray
    opencv_corners: np.ndarray
    model_ok: np.ndarray
    std_px: np.ndarray
    n_markers: int
    dropped: list = field(default_factory=list)
    stretch: str = "percentile"

    @property
    def fraction_model(self) -> float:
        return float(np.mean(self.model_ok)) if len(self.model_ok) else float("nan")


def _opencv_detect(img8: np.ndarray, cvb) -> tuple[np.ndarray, np.ndarray, int]:
    det = cv2.aruco.CharucoDetector(cvb)
    cc, ci, _mc, mi = det.detectBoard(img8)
    if ci is None or cc is None or len(ci) == 0:
        return np.zeros((0, 2)), np.zeros(0, np.int64), 0 if mi is None else len(mi)
    return np.asarray(cc, np.float64).reshape(-1, 2), np.asarray(ci, np.int64).ravel(), len(mi)


def _local_homographies(ids: np.ndarray, corners: np.ndarray, board: CharucoBoard, reach: int = 2):
    """Per corner, the board[mm] -> image[px] homography from the detected corners within ``reach``
    cells (None where fewer than 5 or degenerate)."""
    c, _ = board.inner
    gi, gj = ids % c, ids // c
    obj = board.object_points(ids)[:, :2]
    out = []
    for k in range(len(ids)):
        m = (np.abs(gi - gi[k]) <= reach) & (np.abs(gj - gj[k]) <= reach)
        if m.sum() < 5 or len(np.unique(gi[m])) < 2 or len(np.unique(gj[m])) < 2:
            out.append(None)
            continue
        H, _ = cv2.findHomography(obj[m], corners[m], 0)
        out.append(H if H is not None and np.all(np.isfinite(H)) else None)
    return out


def _refine(f: np.ndarray, ids: np.ndarray, c0: np.ndarray, board: CharucoBoard):
    """X-junction fit of the ChArUco corners with the markers masked out. Returns corners, ok, std."""
    n = len(ids)
    out, ok, std = c0.copy(), np.zeros(n, bool), np.full(n, np.nan)
    Hs = _local_homographies(ids, c0, board)
    use = [k for k in range(n) if Hs[k] is not None]
    if not use:
        return out, ok, std
    s, m = float(board.square_mm), float(board.marker_mm)
    obj = board.object_points(ids)
    dirs = np.zeros((len(use), 2, 2))
    h = np.zeros(len(use))
    Hinv = np.zeros((len(use), 3, 3))
    scale = np.zeros(len(use))
    for a, k in enumerate(use):
        H = Hs[k]
        X, Y = obj[k, 0], obj[k, 1]
        w = H[2, 0] * X + H[2, 1] * Y + H[2, 2]
        p = (H[:2, :2] @ [X, Y] + H[:2, 2]) / w
        J = (H[:2, :2] - np.outer(p, H[2, :2])) / w          # d(image)/d(board) [px/mm]
        ex, ey = J[:, 0], J[:, 1]
        dirs[a, 0], dirs[a, 1] = ex / np.linalg.norm(ex), ey / np.linalg.norm(ey)
        h[a] = s * abs(np.linalg.det(J)) / max(np.linalg.norm(ex), np.linalg.norm(ey))
        Hinv[a] = np.linalg.inv(H)
        scale[a] = np.linalg.svd(J, compute_uv=False).min()
    radius = np.clip(FIT_RADIUS_FRAC * h, FIT_RADIUS_MIN_PX, FIT_RADIUS_MAX_PX)
    # marker squares next to each corner, grown by 2 px of blur (in board mm at the corner's scale)
    half_gap = 0.5 * (s - m)
    grow = 2.0 / np.maximum(scale, 1e-9)

    def keep(Xp, Yp):
        q = np.stack([Xp, Yp, np.ones_like(Xp)], axis=-1).astype(np.float64)      # (C, n, 3)
        b = np.einsum("cij,cnj->cni", Hinv, q)
        bu = b[..., 0] / b[..., 2] - obj[use, 0][:, None]
        bv = b[..., 1] / b[..., 2] - obj[use, 1][:, None]
        lo, hi = half_gap - grow[:, None], s - half_gap + grow[:, None]
        on_marker = np.zeros(bu.shape, bool)
        for sx in (-1.0, 1.0):
            for sy in (-1.0, 1.0):
                x, y = sx * bu, sy * bv
                on_marker |= (x > lo) & (x < hi) & (y > lo) & (y < hi)
        # only the two white squares carry markers: the diagonal of the white quadrants
        return ~on_marker | _black_quadrant(bu, bv, ids[use], board)

    q, blur, sd, res_rel, dth, good = _xjunction_fit(f, c0[use], dirs, radius, keep=keep)
    moved = np.linalg.norm(q - c0[use], axis=1)
    good &= (moved < 0.5 * h) & (blur > 0.051) & (blur < 0.5 * radius - 1e-6)
    good &= (dth > np.sin(np.deg2rad(15.0))) & (res_rel < 0.35)
    idx = np.asarray(use)
    out[idx[good]] = q[good]
    ok[idx[good]] = True
    std[idx[good]] = sd[good]
    return out, ok, std


def _black_quadrant(bu: np.ndarray, bv: np.ndarray, ids: np.ndarray, board: CharucoBoard) -> np.ndarray:
    """True where the board point (offset ``bu, bv`` [mm] from corner ``ids``) lies in a black square."""
    c, _ = board.inner
    i = (ids % c + 1)[:, None] + np.where(bu >= 0, 0, -1)
    j = (ids // c + 1)[:, None] + np.where(bv >= 0, 0, -1)
    return _black_squares(board)[np.clip(j, 0, board.squares_y - 1), np.clip(i, 0, board.squares_x - 1)]


def _black_squares(board: CharucoBoard) -> np.ndarray:
    """(squares_y, squares_x) bool, the squares without a marker."""
    cvb = board.cv()
    centre = np.asarray(cvb.getObjPoints(), float).mean(axis=1)
    black = np.ones((board.squares_y, board.squares_x), bool)
    s = float(board.square_mm)
    black[np.floor(centre[:, 1] / s).astype(int), np.floor(centre[:, 0] / s).astype(int)] = False
    return black


def detect_charuco(img: np.ndarray, board: CharucoBoard, *, refine: str = "model",
                   min_corners: int = 6) -> CharucoDetection | None:
    """Find the corners of a ChArUco board, with their ids; partial views allowed.

    Parameters
    ----------
    img : (H, W) uint8 grey, (H, W) uint16/float IR (stretched to 8 bit for finding, refined on
        its own intensities) or (H, W, 3) colour (RGB)
    board : CharucoBoard
    refine : ``"model"`` (X-junction fit with the markers masked, the default) or ``"opencv"``
        (the detector's own ``cornerSubPix`` corners)
    min_corners : fewer corners than this (after the neighbour check) -> None

    Returns
    -------
    CharucoDetection, or None when fewer than ``min_corners`` corners were found.
    """
    if refine not in ("model", "opencv"):
        raise InputError(f"detect_charuco: refine must be 'model' or 'opencv', found {refine!r}")
    a = np.asarray(img)
    f = gray_float(a, "detect_charuco")
    cvb = board.cv()
    img8 = a if (a.dtype == np.uint8 and a.ndim == 2) else normalize_ir(a)
    c0, ids, nm = _opencv_detect(img8, cvb)
    stretch = "percentile"
    if not (a.dtype == np.uint8 and a.ndim == 2) and len(ids) < board.n_corners:
        c1, i1, n1 = _opencv_detect(normalize_ir(a, gamma=0.5), cvb)
        if len(i1) > len(ids):
            c0, ids, nm, stretch = c1, i1, n1, "gamma"
    if len(ids) < max(int(min_corners), 1):
        return None
    order = np.argsort(ids)
    c0, ids = c0[order], ids[order]
    if refine == "model":
        corners, ok, std = _refine(f, ids, c0, board)
    else:
        corners, ok, std = c0.copy(), np.zeros(len(ids), bool), np.full(len(ids), np.nan)
    # neighbour check: drop the worst disagreeing corner in turn
    cols, _ = board.inner
    keep = np.ones(len(ids), bool)
    dropped = []
    for _ in range(max(1, len(ids) // 4)):
        res, _pred = grid_consistency_ids(corners, ids % cols, ids // cols, exclude=~keep)
        fin = np.isfinite(res) & keep
        if not fin.any():
            break
        k = int(np.flatnonzero(fin)[np.argmax(res[fin])])
        typ = res[fin & (np.arange(len(res)) != k)]
        thr = max(GRID_OUTLIER_PX, 8.0 * float(np.median(typ))) if typ.size else GRID_OUTLIER_PX
        if res[k] <= thr:
            break
        keep[k] = False
        dropped.append(int(ids[k]))
    if keep.sum() < max(int(min_corners), 1):
        return None
    return CharucoDetection(ids[keep], corners[keep], board.object_points(ids[keep]), c0[keep], ok[keep], std[keep],
                            int(nm), dropped, stretch)
