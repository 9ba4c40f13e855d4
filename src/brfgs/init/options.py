"""Options of the initialisation (:func:`brfgs.init.initialize`, ``brfgs init``): one dataclass, the
command line's options generated from it. No heavy imports (the command line reads it at start-up)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from brfgs.data.options import SceneReadOptions
from brfgs.errors import UserError

DEFAULT_MAX_FEATURES = 8192  # features per view kept for matching, after pooling the selected bands
SFM_CONTRAST_THRESHOLD = 0.02  # OpenCV SIFT peak threshold equivalent to COLMAP's default
POSE_MODES = ("known", "sfm", "auto")


def _o(default, help: str, *, flag: str | None = None, aliases: tuple[str, ...] = (), expert: bool = False):
    meta = {"help": help, "aliases": aliases, "expert": expert}
    if flag is not None:
        meta["flag"] = flag
    return field(default=default, metadata=meta)


@dataclass
class InitConfig:
    """Options of SfM or known-pose triangulation (``brfgs init``; the expert ones with ``--help-all``)."""

    max_features: int = _o(DEFAULT_MAX_FEATURES, "Features per view kept for matching.")
    min_inliers: int = _o(15, "Verified matches a view pair needs.")
    min_track_length: int = _o(2, "Drop sparse points seen in fewer views.", flag="--min-track-length",
                               aliases=("--min-track",))
    max_point_error_px: float = _o(2.0, "Drop sparse points with a larger mean reprojection error (px).",
                                   flag="--max-point-error-px", aliases=("--max-point-error",))
    detect_upsample: int = _o(0, "Detect features on a xN upsampled copy (0: 2 for images up to 256 px, else 1).")
    rectify: bool = _o(True, "SfM: detect features on nadir-rectified copies of oblique views.",
                       flag="--rectify/--no-rectify")
    robust_refinement: bool = _o(True, "SfM: finish with retriangulation and a robust bundle adjustment.",
                                 flag="--robust-refinement/--no-robust-refinement")
    threads: int = _o(1, "COLMAP mapping threads (1 = deterministic mapping).")
    match_threads: int = _o(1, "COLMAP matching threads (1 = deterministic matches; -1 = all).")
    seed: int = _o(0, "Random seed (RANSAC, mapping).")
    keep_database: bool = _o(False, "Keep OUT/colmap/database.db.", flag="--keep-database/--drop-database")
    contrast_threshold: float = _o(SFM_CONTRAST_THRESHOLD, "SIFT peak contrast threshold.", expert=True)
    root_sift: bool = _o(True, "RootSIFT descriptors (COLMAP's default).", flag="--root-sift/--plain-sift",
                         expert=True)
    init_min_inliers: Optional[int] = _o(None, "Verified matches of the initial pair (default: from the best pair).",
                                         expert=True)
    min_registered_fraction: float = _o(0.5, "SfM must register at least this fraction of the views.", expert=True)
    detect_max_px: Optional[int] = _o(2048, "Detect features on a downscaled copy above this long side (px).",
                                      expert=True)
    guided_matching: bool = _o(True, "SfM: re-match verified pairs along their epipolar geometry.",
                               flag="--guided-matching/--no-guided-matching", expert=True)
    mapper_max_error_px: float = _o(2.0, "SfM: COLMAP's filter/merge/complete reprojection threshold (px).",
                                    expert=True)
    robust_loss_px: float = _o(1.0, "Scale of the robust bundle adjustment's Cauchy loss (px).", expert=True)

    def validate(self) -> "InitConfig":
        """``self`` when every option is in range; UserError naming the option otherwise."""
        for name, lo in (("max_features", 16), ("min_inliers", 5), ("min_track_length", 2), ("threads", 1),
                         ("detect_upsample", 0)):
            if getattr(self, name) < lo:
                raise UserError(f"{name} must be >= {lo}, got {getattr(self, name)}", field=name)
        if self.match_threads == 0 or self.match_threads < -1:
            raise UserError(f"match_threads must be >= 1 or -1 (all threads), got {self.match_threads}",
                            field="match_threads")
        for name in ("max_point_error_px", "mapper_max_error_px", "robust_loss_px", "contrast_threshold"):
            if not getattr(self, name) > 0:
                raise UserError(f"{name} must be > 0, got {getattr(self, name)}", field=name)
        if not 0 < self.min_registered_fraction <= 1:
            raise UserError(f"min_registered_fraction must be in (0, 1], got {self.min_registered_fraction}",
                            field="min_registered_fraction")
        return self


@dataclass
class InitCommandOptions:
    """Options of ``brfgs init``: reading the scene, the geometry bands and the initialisation."""

    read: SceneReadOptions = field(default_factory=SceneReadOptions, metadata={"flatten": True})
    sfm: InitConfig = field(default_factory=InitConfig, metadata={"flatten": True})
    poses: str = _o("auto", "sfm (COLMAP SfM aligned to ENU), known (triangulate with the scene's poses) or auto "
                    "(known when every frame has a pose, else sfm).", aliases=("-p",))
    strategy: str = _o("efc-top3", "Band strategy (see brfgs select-bands), or all-strategies (the paper's Table 2 "
                       "geometry columns, then efc-top3).", aliases=("-s",))
    top: int = _o(3, "k of the efc strategy.", aliases=("-k",))
    min_separation_nm: float = _o(0.0, "EFC strategies: chosen bands at least this far apart (0 = paper eq. 8).")
    bands: Optional[str] = _o(None, "Explicit band indices i,j,k or a bands.json of select-bands (overrides "
                              "--strategy).")
    overwrite: bool = _o(False, "Replace a finished initialisation in OUT.")
    verbose: bool = _o(False, "Show COLMAP's log.")
    quiet: bool = _o(False, "No progress output.", aliases=("-q",))

    def validate(self) -> "InitCommandOptions":
        self.read.validate()
        self.sfm.validate()
        if self.poses not in POSE_MODES:
            raise UserError(f"poses must be one of {', '.join(POSE_MODES)}, got {self.poses!r}", field="--poses")
        if self.top < 1 or self.min_separation_nm < 0:
            raise UserError("top must be >= 1 and min_separation_nm >= 0", field="--top")
        return self


@dataclass
class ImportColmapOptions:
    """Options of ``brfgs import colmap``: where the COLMAP model, the cubes and the spectral sidecar are."""

    sparse: Optional[Path] = _o(None, "COLMAP sparse model folder (cameras/images/points3D, .bin or .txt) "
                                "(default: PROJECT/sparse/0).")
    images: Optional[Path] = _o(None, "Folder of the hyperspectral cubes, named like the COLMAP images (default: "
                                "PROJECT/images).")
    sidecar: Optional[Path] = _o(None, "Spectral sidecar JSON: wavelengths, fwhm, sun, optional origin and ENU "
                                 "alignment (default: PROJECT/spectral.json if present).")
    overwrite: bool = _o(False, "Replace an existing PROJECT/transforms.json.")
