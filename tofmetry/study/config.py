"""Study configuration (``--config study.toml``), validated with pydantic.

Every key is documented by its ``Field(description=...)``; the effective configuration (defaults
included) is written back to ``OUT/study.toml`` so a run can be reproduced.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from tofmetry.errors import InputError
from tofmetry.io.board_dataset import BoardSpec


class _Cfg(BaseModel):
    model_config = ConfigDict(extra="forbid")


class SimulationConfig(_Cfg):
    """Inputs simulated on the virtual Kinect v2 when no DATA_DIR is given."""

    seed: int = Field(0, description="Random seed of the virtual sensor (runs are deterministic).")
    warmup_duration_s: float = Field(5400.0, gt=0, description="Warm-up series length [s] (study: 90 min).")
    warmup_interval_s: float = Field(15.0, gt=0, description="Interval between warm-up frames [s] (study: 15 s).")
    noise_frames: int = Field(100, ge=2, description="Frames of the static noise capture (study: 100).")
    noise_distance_m: float = Field(1.15, gt=0, description="Wall distance of the noise capture [m] (study: 1.15 m).")
    material_frames: int = Field(20, ge=1, description="Frames of each material/grey board capture.")
    outdoor_frames: int = Field(10, ge=1, description="Frames of the strong-light capture.")
    checkerboard_images: int = Field(20, ge=4, description="Simulated IR checkerboard images (issue: 15-25).")
    tilt_board_poses: int = Field(12, ge=0, description="Checkerboard captures with IR and depth (0.6-1.3 m, turned up "
                                  "to 35 deg) on which the depth tilt the walls cannot show is fitted (calibrate depth "
                                  "--tilt-boards); 0: none.")
    wall_distances_mm: list[float] = Field(
        default_factory=lambda: [800.0] + [1000.0 + 250.0 * i for i in range(21)],
        description="Wall stations [mm] (study: 0.8 m, then 1.0-6.0 m every 0.25 m).",
    )
    wall_frames: int = Field(50, ge=1, description="Frames per wall station (study: 50).")
    validation_distances_mm: list[float] = Field(
        default_factory=lambda: [1125.0, 1625.0, 2375.0, 3125.0, 3875.0],
        description="Held-out wall stations never used for fitting [mm].",
    )
    validation_frames: int = Field(50, ge=1, description="Frames per held-out validation station (as the training stations).")
    scan_views: int = Field(8, ge=2, description="Viewpoints around the object (study: 8).")
    scan_frames: int = Field(10, ge=1, description="Frames per viewpoint (study: 10).")
    scan_radius_m: float = Field(1.0, gt=0, description="Distance camera-object [m] (study: about 1 m).")


class AssessConfig(_Cfg):
    """Sensor assessment (study section 3)."""

    patch_px: int = Field(10, ge=1, description="Side of the square patch for warm-up distance [px] (study: 10x10).")
    warmup_tolerance_mm: float = Field(1.0, gt=0, description="Drift tolerance defining stabilisation [mm].")
    noise_subsets: list[int] = Field(default_factory=lambda: [10, 25, 50, 100],
                                     description="Frame counts n for the std maps (study: 10 and 100).")
    noise_row: int | None = Field(None, description="Image row of the std profile (default: middle row).")


class IntrinsicsConfig(_Cfg):
    """IR-camera geometric calibration (study section 4.1)."""

    board: str = Field("9x6", description="Inner corners COLSxROWS of the checkerboard.")
    square_mm: float = Field(50.0, gt=0, description="Checkerboard square size [mm] (a board.json beside the images overrides it).")

    @field_validator("board")
    @classmethod
    def _board(cls, v: str) -> str:
        BoardSpec.parse(v, 1.0)  # InputError (a ValueError) names the expected form
        return v


class DepthConfig(_Cfg):
    """Depth calibration (study section 4.2)."""

    central_patch_px: int = Field(10, ge=1, description="Central patch for the range-error curve [px] (study: 10x10).")
    max_fit_distance_mm: float = Field(4500.0, gt=0, description="Stations beyond this are reported but not fitted (sensor range).")
    cross_validate: bool = Field(True, description="Leave-one-station-out cross-validation on the training stations "
                                 "of the methods in cv_methods (tofmetry's own calibration carries its blocked "
                                 "validation already).")
    cv_methods: list[str] = Field(default_factory=lambda: ["study"],
                                  description="Methods cross-validated (tofmetry, study, study-poly3); each costs one "
                                  "refit per station.")
    compare_polynomial: bool = Field(True, description="Also fit the study's own method (range spline + cubic "
                                     "polynomial per station) and compare it with tofmetry's on the held-out stations.")
    reference_offset_mm: float = Field(
        20.0, description="Distance from the stations' reference point (tripod fixing screw) forward to the optical "
        "centre, known from the mount; it is taken out of the station distances so that corrected depth is measured "
        "from the optical centre (study §4.2.2: about 2 cm). Any remaining constant is absorbed and reported.")


class ModelConfig(_Cfg):
    """Object reconstruction and accuracy (study section 5)."""

    voxel_mm: float | None = Field(None, description="TSDF voxel size [mm]; default from the sensor noise at range.")
    thresholds_mm: list[float] = Field(default_factory=lambda: [1.0, 2.0, 5.0, 10.0],
                                       description="Deviation thresholds for the 'share within' statistics [mm].")
    compare_uncalibrated: bool = Field(True, description="Also reconstruct without depth calibration, to show what it buys.")
    amplitude_correction: bool = Field(
        True, description="Correct the amplitude-related range bias (study §3.3.1) of the object's views, using the "
        "white wall's IR amplitude as reference (needs IR in wall/ and scan/).")
    amplitude_k_mm_per_ln: float | None = Field(
        None, description="Slope of the amplitude bias [mm per ln(A_white/A)]; unset: the slope measured by the "
        "materials stage, else the study's figure (+12 mm at 1/6 amplitude, i.e. 12/ln 6).")


class RecordingConfig(_Cfg):
    """Real recordings found in DATA_DIR (an iai_kinect2 board recording, Azure Kinect .mkv files)."""

    board: str = Field("5x7", description="Inner corners COLSxROWS of the board of an iai_kinect2 recording (its files "
                       "do not store it; the default is the board of the shared Kinect v2 recording).")
    square_mm: float = Field(30.0, gt=0, description="Square size of that board [mm].")
    judge_fraction: float = Field(2 / 7, gt=0, lt=1, description="Share of the board poses, the last recorded, that "
                                  "no fit sees and that judge the calibration (70 poses: 0050-0069).")
    mkv_max_frames: int | None = Field(None, description="Frames of each .mkv imported (unset: all).")

    @field_validator("board")
    @classmethod
    def _board(cls, v: str) -> str:
        BoardSpec.parse(v, 1.0)
        return v


class StudyConfig(_Cfg):
    """The whole study; sections map to TOML tables."""

    simulation: SimulationConfig = Field(default_factory=SimulationConfig)
    assess: AssessConfig = Field(default_factory=AssessConfig)
    intrinsics: IntrinsicsConfig = Field(default_factory=IntrinsicsConfig)
    depth: DepthConfig = Field(default_factory=DepthConfig)
    model: ModelConfig = Field(default_factory=ModelConfig)
    recording: RecordingConfig = Field(default_factory=RecordingConfig)


def load_config(path: str | Path | None) -> StudyConfig:
    """Load and validate a TOML config (None -> defaults); errors name file and key."""
    if path is None:
        return StudyConfig()
    path = Path(path)
    if not path.is_file():
        raise InputError(f"config file not found: {path}")
    try:
        data = tomllib.loads(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: invalid TOML (not UTF-8 text: byte {exc.start})") from None
    except (tomllib.TOMLDecodeError, RecursionError) as exc:
        raise InputError(f"{path}: invalid TOML ({exc})") from None
    try:
        return StudyConfig.model_validate(data)
    except ValidationError as exc:
        msgs = "; ".join(f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in exc.errors())
        raise InputError(f"{path}: {msgs}") from None


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(type(v))


def config_to_toml(cfg: StudyConfig) -> str:
    """The effective configuration as commented TOML (every key with its description)."""
    lines = ["# tofmetry study configuration (effective values, defaults included)", ""]
    for section, model in cfg:
        lines.append(f"[{section}]")
        doc = (type(model).__doc__ or "").strip().splitlines()[0]
        lines.append(f"# {doc}")
        for name, finfo in type(model).model_fields.items():
            val = getattr(model, name)
            lines.append(f"# {finfo.description}")
            if val is None:
                lines.append(f"# {name} = (unset: automatic)")
            else:
                lines.append(f"{name} = {_toml_value(val)}")
        lines.append("")
    return "\n".join(lines)
