"""Rigid transforms between sensor frames (e.g. IR/depth camera -> colour camera)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofmetry.errors import InputError


@dataclass(frozen=True)
class Extrinsics:
    """Rigid transform ``p_to = R @ p_from + t``.

    Parameters
    ----------
    rotation : (3, 3) float64
        Proper rotation matrix.
    translation : (3,) float64
        Translation [m].
    source, target : str
        Frame names, e.g. ``"ir"`` -> ``"color"``.
    """

    rotation: np.ndarray
    translation: np.ndarray
    source: str = "ir"
    target: str = "color"

    def __post_init__(self) -> None:
        R = np.asarray(self.rotation, dtype=np.float64).reshape(3, 3)
        t = np.asarray(self.translation, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(R)) or not np.all(np.isfinite(t)):
            raise InputError("extrinsics: rotation and translation must be finite")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
            raise InputError(f"extrinsics: rotation is not a proper rotation matrix (R R^T != I or det < 0): {R.tolist()}")
        object.__setattr__(self, "rotation", R)
        object.__setattr__(self, "translation", t)

    @classmethod
    def identity(cls, source: str = "ir", target: str = "color") -> "Extrinsics":
        return cls(np.eye(3), np.zeros(3), source, target)

    @classmethod
    def from_matrix(cls, T: np.ndarray, source: str = "ir", target: str = "color") -> "Extrinsics":
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4):
            raise InputError(f"extrinsics: expected a 4x4 matrix, found shape {T.shape}")
        return cls(T[:3, :3], T[:3, 3], source, target)

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous transform."""
        T = np.eye(4)
        T[:3, :3] = self.rotation
        T[:3, 3] = self.translation
        return T

    def inverse(self) -> "Extrinsics":
        return Extrinsics(self.rotation.T, -self.rotation.T @ self.translation, self.target, self.source)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform (N, 3) points from ``source`` to ``target`` frame."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return p @ self.rotation.T + self.translation

    def to_dict(self) -> dict:
        return {"source": self.source, "target": self.target,
                "rotation": self.rotation.tolist(), "translation_m": self.translation.tolist()}

    @classmethod
    def from_dict(cls, d: dict, *, source_name: str = "extrinsics") -> "Extrinsics":
        try:
            return cls(np.array(d["rotation"], float), np.array(d["translation_m"], float),
                       d.get("source", "ir"), d.get("target", "color"))
        except KeyError as exc:
            raise InputError(f"{source_name}: missing key {exc}; expected rotation (3x3) and translation_m (3)") from None
