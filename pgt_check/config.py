"""Typed run configuration: frozen dataclasses, strict loading (unknown keys are errors).

``RunConfig.from_dict`` builds a config from plain data (a JSON/TOML file or the CLI) and raises
``ConfigError`` naming the bad key and the allowed ones. The resolved config is written to the
run directory; ``measurement_fingerprint`` hashes the fields that change per-frame measurements
(thresholds of the verdict do not: a new threshold never re-renders).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from pgt_check.errors import ConfigError

#: config sections whose change invalidates stored per-frame measurements
MEASUREMENT_SECTIONS = ("input", "render", "match", "homography", "enhance", "pose")


@dataclass(frozen=True)
class HomographyConfig:
    """Robust estimation settings (pixels are those of the images that were matched)."""

    ransac_threshold_px: float = 3.0
    confidence: float = 0.9999
    max_iters: int = 10000
    min_matches: int = 12
    min_inliers: int = 12
    max_condition: float = 1e7
    #: the warped image may not shrink or grow by more than this factor in area
    max_area_ratio: float = 16.0


@dataclass(frozen=True)
class ReferenceConfig:
    mode: Literal["nearest", "self", "none"] = "nearest"
    #: scene units that count as much as ``rotation_scale_deg`` degrees; None = 10 % of the
    #: trajectory's extent (scale-free default)
    translation_scale: float | None = None
    rotation_scale_deg: float = 10.0
    time_scale_s: float | None = None
    #: hard limits; None = no limit on translation (rotation is always limited)
    max_translation: float | None = None
    max_rotation_deg: float = 45.0
    min_frame_gap: int = 1
    #: references tried per frame; the enhanced result with the most homography inliers is
    #: kept (a reference whose own pose is wrong paints texture on the wrong surfaces, which
    #: costs inliers, so a second reference guards against one bad neighbour)
    count: int = 2


def _check_name(section: str, key: str, value: str, table: Any) -> None:
    """``value`` must be a key of the backend table ``table`` (the one source of the names)."""
    if value not in table:
        raise ValueError(f"{section}.{key}: unknown {value!r} (allowed: {', '.join(table)})")


@dataclass(frozen=True)
class InputConfig:
    trajectory: str = ""
    #: "auto" or a name of ``pgt_check.io.FORMATS``
    format: str = "auto"
    images: str | None = None
    camera: str | None = None
    sensors: str | None = None
    #: nerfstudio: dataparser_transforms.json whose transform and scale are undone
    dataparser_transforms: str | None = None
    mesh: str = ""

    def __post_init__(self) -> None:
        from pgt_check.registry import FORMATS

        _check_name("input", "format", self.format, ("auto", *FORMATS))


@dataclass(frozen=True)
class RenderConfig:
    #: a name of ``pgt_check.render.BACKENDS``
    backend: str = "moderngl"
    #: "auto" picks texture > vertex colours > shaded geometry from what the mesh has
    shading: Literal["auto", "vertex", "texture", "shaded"] = "auto"

    def __post_init__(self) -> None:
        from pgt_check.registry import RENDER_BACKENDS

        _check_name("render", "backend", self.backend, RENDER_BACKENDS)


@dataclass(frozen=True)
class MatchConfig:
    method: str = "sift"
    max_keypoints: int = 4096
    #: longest image side used for matching (render is made at that size); None = original
    resize_max: int | None = 640
    #: LoFTR checkpoint (no LoFTR weights are bundled); only for method "loftr"
    loftr_weights: str | None = None

    def __post_init__(self) -> None:
        from pgt_check.registry import MATCHERS

        _check_name("match", "method", self.method, MATCHERS)


@dataclass(frozen=True)
class EnhanceConfig:
    """The enhanced path (render enhanced with a reference photo, matched again).

    mode: "never" (raw only), "always", or "auto": enhance only frames whose raw result is not
    decisive: the raw homography failed, it has fewer than ``auto_min_inliers`` inliers, or its
    corner error lies within ``auto_margin`` x threshold of the threshold.
    method: "mariner" (the learned MaRINeR core) or "reproject" (classical: the reference photo
    projected through the mesh into the render's view).
    """

    mode: Literal["never", "auto", "always"] = "auto"
    #: default "reproject": on the shared data it beats the shipped (CPU-trained) MaRINeR
    #: weights, see reports/raw_vs_enhanced.md and reports/mariner_quality.md
    method: str = "reproject"
    weights: str | None = None
    iterations: int | None = None
    short_side: int = 160
    device: str = "cpu"
    auto_min_inliers: int = 40
    auto_margin: float = 0.5
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)

    def __post_init__(self) -> None:
        from pgt_check.registry import ENHANCERS

        _check_name("enhance", "method", self.method, ENHANCERS)


@dataclass(frozen=True)
class PoseConfig:
    """The PnP pose-error estimate from the render depth (pycolmap)."""

    enabled: bool = True
    max_error_px: float = 4.0
    min_inliers: int = 12


@dataclass(frozen=True)
class VerdictConfig:
    #: PASS threshold on the corner error in original photo pixels; None = rel_diag * diagonal
    threshold_px: float | None = None
    threshold_rel_diag: float = 0.02
    #: render coverage below this fraction -> UNVERIFIABLE(low_coverage)
    min_coverage: float = 0.05
    min_inliers: int = 15
    min_inlier_ratio: float = 0.0
    #: the gate passes while FAIL frames / all frames <= this
    max_fail_fraction: float = 0.0
    #: and while UNVERIFIABLE frames / all frames <= this (1.0 = never gate on them)
    max_unverifiable_fraction: float = 1.0

    def threshold_for(self, width: int, height: int) -> float:
        """The PASS threshold in original photo pixels for an image of this size."""
        if self.threshold_px is not None:
            return float(self.threshold_px)
        return float(self.threshold_rel_diag * math.hypot(width, height))


@dataclass(frozen=True)
class CorrectConfig:
    """Pose corrections after the verdicts (``pgt_check.corrections``): iterate render -> raw
    match -> PnP from each frame's PnP estimate; writes corrected_trajectory.txt."""

    #: which frames: "fail" (FAIL verdicts), "all" (every measured frame) or "none"
    frames: Literal["none", "fail", "all"] = "fail"
    rounds: int = 3
    #: PnP bootstrap resamples for the uncertainty (0 = the last update only)
    bootstrap: int = 12

    def __post_init__(self) -> None:
        if self.rounds < 1:
            raise ValueError(f"correct.rounds must be >= 1, got {self.rounds}")
        if self.bootstrap < 0:
            raise ValueError(f"correct.bootstrap must be >= 0, got {self.bootstrap}")


@dataclass(frozen=True)
class RunConfig:
    input: InputConfig = field(default_factory=InputConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    match: MatchConfig = field(default_factory=MatchConfig)
    homography: HomographyConfig = field(default_factory=HomographyConfig)
    enhance: EnhanceConfig = field(default_factory=EnhanceConfig)
    pose: PoseConfig = field(default_factory=PoseConfig)
    verdict: VerdictConfig = field(default_factory=VerdictConfig)
    correct: CorrectConfig = field(default_factory=CorrectConfig)
    #: frames that get image panels in the report (all FAIL/UNVERIFIABLE first, then the worst)
    report_details: int = 40
    out: str = "pgt-check-out"
    limit: int | None = None
    fail_fast: bool = False
    absolute_paths: bool = False
    #: how frames are spread: in-process, a local process pool, or a Dask cluster
    executor: Literal["serial", "process", "dask"] = "serial"
    #: worker processes (process / local Dask cluster); None = all CPU cores
    workers: int | None = None
    #: address of an existing Dask scheduler (tcp://host:8786); None = start a LocalCluster
    scheduler: str | None = None
    #: keep frames already measured with the same settings in ``out``, recompute the others
    resume: bool = False
    #: discard the per-frame records already in ``out`` and start fresh
    overwrite: bool = False
    #: times a frame whose worker process died is run again before it is UNVERIFIABLE
    retries: int = 1

    def __post_init__(self) -> None:
        if self.workers is not None and self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers}")
        if self.retries < 0:
            raise ValueError(f"retries must be >= 0, got {self.retries}")
        if self.resume and self.overwrite:
            raise ValueError("resume and overwrite exclude each other: pick one")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunConfig:
        return from_dict(cls, data)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def measurement_settings(self) -> dict[str, Any]:
        """Every setting that changes a per-frame measurement.

        The measurement sections, plus the verdict settings the measurement stage reads:
        ``min_coverage`` (frames below it are not matched) and, with ``enhance.mode = auto``,
        the threshold (the auto-enhance decision depends on it).
        """
        d = self.to_dict()
        keep: dict[str, Any] = {k: d[k] for k in MEASUREMENT_SECTIONS}
        used = {"min_coverage": self.verdict.min_coverage}
        if self.enhance.mode == "auto":
            used["threshold_px"] = self.verdict.threshold_px
            used["threshold_rel_diag"] = self.verdict.threshold_rel_diag
        keep["verdict"] = used
        return keep

    def measurement_fingerprint(self, **extra: Any) -> str:
        """Hash of ``measurement_settings`` (and ``extra``, e.g. the record layout version)."""
        blob = json.dumps({**self.measurement_settings(), **extra}, sort_keys=True,
                          default=str).encode()
        return hashlib.sha256(blob).hexdigest()[:16]


#: Named presets (merged under the CLI options and any --config file). The points were chosen
#: from the error-vs-runtime Pareto front in reports/error_vs_runtime.md.
PRESETS: dict[str, dict[str, Any]] = {
    "fast": {
        "match": {"method": "sift", "resize_max": 320},
        "enhance": {"mode": "never"},
        "pose": {"enabled": False},
    },
    "balanced": {
        "match": {"method": "sift", "resize_max": 320},
        "enhance": {"mode": "auto", "method": "reproject"},
    },
    "accurate": {
        "match": {"method": "xfeat", "resize_max": 640},
        "enhance": {"mode": "auto", "method": "reproject"},
    },
}


def _check_value(cls_name: str, name: str, tp: Any, value: Any) -> Any:
    origin = typing.get_origin(tp)
    if origin is Literal:
        if value not in typing.get_args(tp):
            raise ConfigError(
                f"{cls_name}.{name}: {value!r} is not one of {list(typing.get_args(tp))}"
            )
        return value
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        for a in args:
            if a is type(None):
                continue
            try:
                return _check_value(cls_name, name, a, value)
            except ConfigError:
                continue
        raise ConfigError(f"{cls_name}.{name}: {value!r} does not fit {tp}")
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise ConfigError(f"{cls_name}.{name}: expected a table, got {value!r}")
        return from_dict(tp, value)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{cls_name}.{name}: expected true/false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{cls_name}.{name}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{cls_name}.{name}: expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{cls_name}.{name}: expected a string, got {value!r}")
        return value
    return value


def from_dict(cls: type, data: dict[str, Any]):
    """Build dataclass ``cls`` from ``data``; unknown keys and mistyped values raise ConfigError."""
    if not isinstance(data, dict):
        raise ConfigError(f"{cls.__name__}: expected a table, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - fields)
    if unknown:
        raise ConfigError(
            f"{cls.__name__}: unknown key {unknown[0]!r} (allowed: {', '.join(sorted(fields))})"
        )
    kwargs = {k: _check_value(cls.__name__, k, hints[k], v) for k, v in data.items()}
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{cls.__name__}: {err}") from err


def load_config_file(path: str | Path) -> dict[str, Any]:
    """Read a JSON or TOML config file into a dict (validated later by ``from_dict``)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}")
    text = path.read_text()
    try:
        if path.suffix == ".toml":
            import tomllib

            return tomllib.loads(text)
        return json.loads(text)
    except (ValueError, json.JSONDecodeError) as err:
        raise ConfigError(f"{path}: cannot parse config: {err}") from err


def merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    """Recursive dict merge: values in ``override`` win; nested tables merge."""
    out = dict(base)
    for k, v in override.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge(out[k], v)
        else:
            out[k] = v
    return out
