"""Simulated scenes: planes, boards and meshes in world coordinates [m].

A :class:`Scene` is a list of surfaces; :meth:`Scene.intersect` casts rays from one origin
and returns the nearest hit of every ray with its albedo, incidence, region label and (for
reflective samples) a static, spatially uneven bias field. Planar surfaces are intersected
analytically; triangle meshes with Open3D's ``RaycastingScene``.

Conventions: world frame in metres. For the wall and board scenes the camera at the
identity pose looks along +z (x right, y down). Mesh scenes (:func:`mesh_on_ground`,
:func:`outdoor_table`) use a z-up world with the ground plane at z = 0.
Label 0 = background / nothing of interest; ``Scene.labels`` names the others.
"""

from __future__ import annotations

import math

import numpy as np

from tofmetry.errors import InputError
from tofmetry.simulate.surfaces import Hits, MeshSurface, PlaneSurface, Scene, Texture, _uniform_texture

__all__ = ["Hits", "MeshSurface", "PlaneSurface", "Scene", "Texture", "wall", "checkerboard", "charuco", "grey_board",
           "material_board", "mesh_on_ground", "balustrade", "outdoor_table", "ground_plane", "rotation_xyz",
           "GREY_LEVELS", "MATERIALS"]


# ---------------------------------------------------------------- helpers
def rotation_xyz(rx_deg: float = 0.0, ry_deg: float = 0.0, rz_deg: float = 0.0) -> np.ndarray:
    """(3, 3) rotation ``Rz @ Ry @ Rx`` from angles in degrees."""
    a, b, c = (math.radians(v) for v in (rx_deg, ry_deg, rz_deg))
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _uneven_field(s: np.ndarray, t: np.ndarray, seed: int) -> np.ndarray:
    """Smooth, uneven 0..1 field on a surface (sum of random sinusoids), for reflective samples."""
    rng = np.random.default_rng(seed)
    acc = np.zeros_like(s)
    for _ in range(4):
        k = rng.uniform(20.0, 90.0, 2) * rng.choice([-1, 1], 2)
        acc += np.sin(k[0] * s + k[1] * t + rng.uniform(0, 2 * np.pi))
    return np.clip(0.5 + acc / 5.0, 0.0, 1.0)


# ---------------------------------------------------------------- scenes
def wall(distance_m: float = 1.0, tilt_deg: tuple[float, float] = (0.0, 0.0), albedo: float = 0.8) -> Scene:
    """Infinite plane facing the camera at the identity pose.

    Parameters
    ----------
    distance_m : float
        Distance of the plane from the world origin along +z [m] (optical-centre distance
        for a camera at the identity pose).
    tilt_deg : (rx, ry)
        Rotation of the plane normal about x then y [deg] (0, 0 = parallel to the sensor).
    albedo : float
        IR albedo (0.8 = white).
    """
    if not distance_m > 0:
        raise InputError(f"scenes.wall: distance_m must be > 0, found {distance_m}")
    R = rotation_xyz(tilt_deg[0], tilt_deg[1])
    e1, e2 = R[:, 0], R[:, 1]
    surf = PlaneSurface(np.array([0.0, 0.0, distance_m]), e1, e2, None, _uniform_texture(albedo, 1))
    n = surf.normal
    return Scene("wall", [surf], {1: "wall"},
                 {"type": "wall", "distance_m": distance_m, "tilt_deg": list(tilt_deg), "albedo": albedo,
                  "plane_normal": n.tolist(), "plane_point_m": [0.0, 0.0, distance_m],
                  "plane_d_m": float(n @ np.array([0.0, 0.0, distance_m]))}, smooth=True)


def checkerboard(cols: int = 9, rows: int = 6, square_m: float = 0.04, board_to_world: np.ndarray | None = None,
                 margin_m: float = 0.05, black: float = 0.133, white: float = 0.8,
                 pose: np.ndarray | None = None) -> Scene:
    """Printed checkerboard with ``cols x rows`` INNER corners.

    Board frame: origin at the first inner corner, x along the columns, y along the rows,
    z into the board (OpenCV object points ``(i s, j s, 0)``). The board has
    ``(cols+1) x (rows+1)`` squares plus a white margin; square (0, 0) (top-left, outside
    the first corner) is black. Labels: 1 = white (incl. margin), 2 = black.

    Parameters
    ----------
    board_to_world : (4, 4), default places the board 1 m in front of an identity camera
        (``pose`` is an alias).
    """
    board_to_world = pose if board_to_world is None else board_to_world
    if cols < 2 or rows < 2:
        raise InputError(f"scenes.checkerboard: need at least 2x2 inner corners, found {cols}x{rows}")
    T = np.eye(4) if board_to_world is None else np.asarray(board_to_world, float)
    if board_to_world is None:
        T[:3, 3] = [-(cols - 1) * square_m / 2, -(rows - 1) * square_m / 2, 1.0]
    s = square_m

    def tex(u, v):
        i = np.floor(u / s).astype(np.int64)
        j = np.floor(v / s).astype(np.int64)
        inside = (u >= -s) & (u < cols * s) & (v >= -s) & (v < rows * s)
        blk = inside & ((i + j) % 2 == 1)
        alb = np.where(blk, black, white)
        return alb, np.where(blk, 2, 1).astype(np.int32), np.zeros(u.shape, bool), np.zeros(u.shape)

    ext = (-s - margin_m, cols * s + margin_m, -s - margin_m, rows * s + margin_m)
    surf = PlaneSurface(T[:3, 3].copy(), T[:3, 0].copy(), T[:3, 1].copy(), ext, tex)
    return Scene("checkerboard", [surf], {1: "white", 2: "black"},
                 {"type": "checkerboard", "cols": cols, "rows": rows, "square_m": square_m,
                  "board_to_world": T.tolist(), "albedo_black": black, "albedo_white": white})


def charuco_pattern(squares_x: int, squares_y: int, square_m: float, marker_m: float,
                    dictionary: str = "DICT_4X4_50") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The printed pattern of an OpenCV ChArUco board (``cv2.aruco.CharucoBoard``, default pattern).

    Returns
    -------
    black : (squares_y, squares_x) bool, the black squares (row j, column i)
    marker_rect : (M, 2) [m], top-left corner (x, y) of each marker in the board frame (board
        frame of OpenCV: origin at the board's outer top-left corner, x along the squares, y down)
    bits : (M, n+2, n+2) bool, each marker's modules including its black border (True = white)
    """
    import cv2

    if squares_x < 2 or squares_y < 2 or not 0 < marker_m < square_m:
        raise InputError(f"scenes.charuco: need >= 2x2 squares and 0 < marker_m < square_m, found "
                         f"{squares_x}x{squares_y}, square {square_m}, marker {marker_m}")
    try:
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    except AttributeError:
        raise InputError(f"scenes.charuco: unknown ArUco dictionary {dictionary!r} (e.g. DICT_4X4_50)") from None
    b = cv2.aruco.CharucoBoard((int(squares_x), int(squares_y)), float(square_m), float(marker_m), d)
    corners = np.asarray(b.getObjPoints(), float)           # (M, 4, 3): TL, TR, BR, BL
    ids = np.asarray(b.getIds()).ravel()
    n = d.markerSize + 2
    bits = np.stack([cv2.aruco.generateImageMarker(d, int(k), n, borderBits=1) > 127 for k in ids])
    black = np.ones((squares_y, squares_x), bool)
    centre = corners.mean(axis=1)
    black[np.floor(centre[:, 1] / square_m).astype(int), np.floor(centre[:, 0] / square_m).astype(int)] = False
    return black, corners[:, 0, :2].copy(), bits


def charuco(squares_x: int = 9, squares_y: int = 7, square_m: float = 0.08, marker_m: float = 0.056,
            dictionary: str = "DICT_4X4_50", board_to_world: np.ndarray | None = None, margin_m: float = 0.02,
            black: float = 0.133, white: float = 0.8) -> Scene:
    """Printed ChArUco board (OpenCV's ``CharucoBoard`` pattern) as an albedo texture on a plane.

    Board frame (OpenCV's): origin at the outer top-left corner of the squares, x along the
    ``squares_x`` columns, y along the rows (down on the print), z into the board; chessboard
    corner ``k`` (OpenCV id, row-major over the ``(squares_x-1) x (squares_y-1)`` inner corners)
    is at ``((i+1) s, (j+1) s, 0)``. Markers are exact module grids (no resampling of a bitmap).
    Labels: 1 = white (incl. margin and marker modules), 2 = black.

    Parameters
    ----------
    squares_x, squares_y : squares along x and y; square_m, marker_m : square and marker side [m]
    dictionary : name of an OpenCV predefined dictionary (``cv2.aruco.DICT_...``)
    board_to_world : (4, 4); default centres the board 1 m in front of an identity camera
    margin_m : white margin around the squares [m]
    """
    blk, rect, bits = charuco_pattern(squares_x, squares_y, square_m, marker_m, dictionary)
    T = np.eye(4) if board_to_world is None else np.asarray(board_to_world, float)
    if board_to_world is None:
        T[:3, 3] = [-squares_x * square_m / 2, -squares_y * square_m / 2, 1.0]
    s, m, nb = square_m, marker_m, bits.shape[1]
    # marker index per square (-1: none)
    mk = -np.ones((squares_y, squares_x), np.int64)
    mk[np.floor((rect[:, 1] + m / 2) / s).astype(int), np.floor((rect[:, 0] + m / 2) / s).astype(int)] = np.arange(len(rect))

    def tex(u, v):
        i = np.floor(u / s).astype(np.int64)
        j = np.floor(v / s).astype(np.int64)
        inside = (i >= 0) & (i < squares_x) & (j >= 0) & (j < squares_y)
        ic, jc = np.clip(i, 0, squares_x - 1), np.clip(j, 0, squares_y - 1)
        is_black = inside & blk[jc, ic]
        k = np.where(inside, mk[jc, ic], -1)
        has = k >= 0
        kk = np.maximum(k, 0)
        a = np.floor((u - rect[kk, 0]) / m * nb).astype(np.int64)
        b = np.floor((v - rect[kk, 1]) / m * nb).astype(np.int64)
        in_m = has & (a >= 0) & (a < nb) & (b >= 0) & (b < nb)
        mod_white = bits[kk, np.clip(b, 0, nb - 1), np.clip(a, 0, nb - 1)]
        dark = is_black | (in_m & ~mod_white)
        return (np.where(dark, black, white), np.where(dark, 2, 1).astype(np.int32), np.zeros(u.shape, bool),
                np.zeros(u.shape))

    ext = (-margin_m, squares_x * s + margin_m, -margin_m, squares_y * s + margin_m)
    surf = PlaneSurface(T[:3, 3].copy(), T[:3, 0].copy(), T[:3, 1].copy(), ext, tex)
    return Scene("charuco", [surf], {1: "white", 2: "black"},
                 {"type": "charuco", "squares_x": squares_x, "squares_y": squares_y, "square_m": square_m,
                  "marker_m": marker_m, "dictionary": dictionary, "board_to_world": T.tolist(),
                  "albedo_black": black, "albedo_white": white})


#: Grey levels of :func:`grey_board` (white 0.8 ... black 0.133 = 1/6 of white).
GREY_LEVELS = (0.8, 0.62, 0.48, 0.36, 0.26, 0.19, 0.133)


def grey_board(distance_m: float = 1.0, cols: int = 5, rows: int = 4, square_m: float = 0.12,
               background_albedo: float = 0.8) -> Scene:
    """Grey-level checkerboard (paper §3.3.1, Fig. 4) in front of an identity camera.

    ``cols x rows`` squares, albedos cycling through :data:`GREY_LEVELS` (white to black,
    black = 1/6 of white), on a white wall ``distance_m`` away. Label ``1 + k`` = square k
    (row-major), named ``"<level>_<k>"``; white squares are the reference regions.
    """
    w, h = cols * square_m, rows * square_m
    x0, y0 = -w / 2, -h / 2
    levels = [GREY_LEVELS[(k * 3) % len(GREY_LEVELS)] for k in range(cols * rows)]

    def tex(u, v):
        i = np.clip(np.floor((u - x0) / square_m).astype(np.int64), 0, cols - 1)
        j = np.clip(np.floor((v - y0) / square_m).astype(np.int64), 0, rows - 1)
        k = j * cols + i
        return np.asarray(levels)[k], (k + 1).astype(np.int32), np.zeros(u.shape, bool), np.zeros(u.shape)

    def tex_all(u, v):
        inside = (u >= x0) & (u < x0 + w) & (v >= y0) & (v < y0 + h)
        alb, lab, refl, rb = tex(u, v)
        return (np.where(inside, alb, background_albedo), np.where(inside, lab, 0).astype(np.int32), refl, rb)

    # the board is modelled flush with the wall: one plane, albedo and labels from the texture
    board = PlaneSurface(np.array([0.0, 0.0, distance_m]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), None, tex_all)
    names = {}
    squares = []
    for k, a in enumerate(levels):
        i, j = k % cols, k // cols
        name = ("white" if a == GREY_LEVELS[0] else "black" if a == GREY_LEVELS[-1] else f"grey{a:.2f}") + f"_{k}"
        names[k + 1] = name
        squares.append({"name": name, "label": k + 1, "albedo": a, "reflective": False,
                        "rect_m": [x0 + i * square_m, y0 + j * square_m, x0 + (i + 1) * square_m, y0 + (j + 1) * square_m],
                        "reference": a == GREY_LEVELS[0]})
    return Scene("grey_board", [board], names | {0: "wall"},
                 {"type": "grey_board", "distance_m": distance_m, "board_z_m": distance_m, "samples": squares})


#: Material samples of :func:`material_board`: name -> (albedo, reflective).
MATERIALS = {
    "white_paper": (0.8, False), "grey_card": (0.4, False), "black_fabric": (0.1, False),
    "wood": (0.45, False), "cork": (0.33, False), "cd": (0.15, True),
}


def material_board(distance_m: float = 1.0, sample_m: float = 0.12, gap_m: float = 0.05,
                   board_albedo: float = 0.8, reflective_max_mm: float = 60.0) -> Scene:
    """White board with material samples (paper §3.3.1) in front of an identity camera.

    Samples of :data:`MATERIALS` in a 3 x 2 grid; the "cd" sample is reflective: low
    amplitude and an uneven extra bias up to ``reflective_max_mm`` (paper: up to 6 cm).
    Labels: 0 = board, 1.. = samples in :data:`MATERIALS` order.
    """
    names = list(MATERIALS)
    ncol, nrow = 3, 2
    pitch = sample_m + gap_m
    x0 = -(ncol * pitch - gap_m) / 2
    y0 = -(nrow * pitch - gap_m) / 2
    rects = []
    samples = []
    for k, name in enumerate(names):
        alb, refl = MATERIALS[name]
        i, j = k % ncol, k // ncol
        sx, sy = x0 + i * pitch, y0 + j * pitch
        rects.append((sx, sy, alb, refl, k + 1))
        samples.append({"name": name, "label": k + 1, "albedo": alb, "reflective": refl,
                        "rect_m": [sx, sy, sx + sample_m, sy + sample_m], "reference": name == "white_paper"})

    def tex(u, v):
        n = u.shape[0]
        alb, lab = np.full(n, board_albedo), np.zeros(n, np.int32)
        refl, rb = np.zeros(n, bool), np.zeros(n)
        for sx, sy, a, r, lb in rects:
            m = (u >= sx) & (u < sx + sample_m) & (v >= sy) & (v < sy + sample_m)
            alb[m], lab[m], refl[m] = a, lb, r
            if r:
                rb[m] = _uneven_field(u[m], v[m], seed=17 + lb)
        return alb, lab, refl, rb

    # samples are modelled flush with the board (one plane; labels and albedos from the texture)
    z = distance_m
    surfs = [PlaneSurface(np.array([0.0, 0.0, z]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), None, tex,
                          reflective_max_mm)]
    labels = {0: "board"} | {k + 1: n for k, n in enumerate(names)}
    return Scene("material_board", surfs, labels,
                 {"type": "material_board", "distance_m": distance_m, "board_z_m": z, "samples": samples})


def ground_plane(size_m: float = 6.0, albedo: float = 0.45, label: int = 0) -> PlaneSurface:
    """Square ground plane z = 0 (z-up world), centred at the origin."""
    h = size_m / 2
    return PlaneSurface(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), (-h, h, -h, h),
                        _uniform_texture(albedo, label))


def mesh_on_ground(mesh_vertices: np.ndarray, mesh_triangles: np.ndarray, albedo: float = 0.7,
                   ground_albedo: float = 0.45, ground_size_m: float = 6.0, place_on_ground: bool = True,
                   mat=None) -> Scene:
    """Any triangle mesh standing on a ground plane (z-up world, ground z = 0).

    Parameters
    ----------
    mesh_vertices : (V, 3) float [m]; mesh_triangles : (F, 3) int.
    place_on_ground : translate the mesh so that its lowest point is at z = 0 and its
        bounding-box centre on the z axis. ``Scene.info["mesh_vertices_world"]`` is the mesh
        actually placed (use it as the reference). Labels: 0 = ground, 1 = object.
    mat : a :class:`~tofmetry.simulate.mat.DotMat` lying on the ground centred on the z axis (None: none)
    """
    v = np.asarray(mesh_vertices, np.float64).reshape(-1, 3)
    f = np.asarray(mesh_triangles, np.int64).reshape(-1, 3)
    if v.shape[0] < 3 or f.shape[0] < 1:
        raise InputError(f"scenes.mesh_on_ground: empty mesh ({v.shape[0]} vertices, {f.shape[0]} triangles)")
    if f.min() < 0 or f.max() >= v.shape[0]:
        raise InputError("scenes.mesh_on_ground: triangle indices out of range of the vertices")
    if place_on_ground:
        c = (v.min(0) + v.max(0)) / 2
        v = v - np.array([c[0], c[1], v[:, 2].min()])
    ground = ground_plane(ground_size_m, ground_albedo, 0)
    info = {"type": "mesh_on_ground", "albedo": albedo, "ground_albedo": ground_albedo,
            "mesh_vertices_world": v, "mesh_triangles": f}
    if mat is not None:
        from tofmetry.simulate.mat import dot_mat_texture

        ground.texture = dot_mat_texture(mat, ground_albedo, 0)
        info["mat"] = mat.to_dict()
    surfs = [ground, MeshSurface(v, f, albedo, 1)]
    return Scene("mesh_on_ground", surfs, {0: "ground", 1: "object"}, info)


def balustrade(**kwargs) -> Scene:
    """A balustrade-like object (see :func:`tofmetry.simulate.meshes.balustrade_mesh`) on the ground."""
    from tofmetry.simulate.meshes import balustrade_mesh

    v, f = balustrade_mesh()
    sc = mesh_on_ground(v, f, **kwargs)
    sc.name = "balustrade"
    return sc


def _box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def outdoor_table(background_m: float = 9.0) -> Scene:
    """Table (1.2 x 0.8 m, 0.75 m high) with a 0.3 m box on it, far wall behind (paper §3.3.2, Fig. 5).

    z-up world, ground z = 0, table centred at (0, 2.2, 0); the background wall at
    y = ``background_m`` is beyond the range limit. Labels: 0 ground, 1 table top,
    2 legs, 3 box, 4 background.
    """
    parts = []
    top = _box((-0.6, 1.8, 0.72), (0.6, 2.6, 0.75))
    parts.append(MeshSurface(*top, albedo=0.55, label=1))
    legs_v, legs_f = [], []
    for k, (x, y) in enumerate([(-0.55, 1.85), (0.55, 1.85), (-0.55, 2.55), (0.55, 2.55)]):
        v, f = _box((x - 0.02, y - 0.02, 0.0), (x + 0.02, y + 0.02, 0.72))
        legs_v.append(v)
        legs_f.append(f + 8 * k)
    parts.append(MeshSurface(np.vstack(legs_v), np.vstack(legs_f), albedo=0.12, label=2))
    parts.append(MeshSurface(*_box((-0.15, 2.05, 0.75), (0.15, 2.35, 1.05)), albedo=0.7, label=3))
    back = PlaneSurface(np.array([0.0, background_m, 0.0]), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]),
                        (-20, 20, 0, 10), _uniform_texture(0.5, 4))
    surfs = [ground_plane(40.0, 0.3, 0)] + parts + [back]
    return Scene("outdoor_table", surfs, {0: "ground", 1: "table_top", 2: "table_legs", 3: "box", 4: "background"},
                 {"type": "outdoor_table", "background_m": background_m})
