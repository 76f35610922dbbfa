"""Typed run configuration: frozen dataclasses, strict loading (unknown keys are errors). The
measuring sections it composes are in ``measure``, the judging ones in ``judge``.

``RunConfig.from_dict`` builds a config from plain data (a JSON/TOML file or the CLI) and raises
``ConfigError`` naming the bad key and the allowed ones. The resolved config is written to the
run directory; ``measurement_fingerprint`` hashes the fields that change per-frame measurements
(thresholds of the verdict do not: a new threshold never re-renders).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from pgt_check.config.judge import (
    MOVED_KEYS,
    CorrectConfig,
    GateConfig,
    RunChecksConfig,
    VerdictConfig,
)
from pgt_check.config.load import check_range as _check_range
from pgt_check.config.load import from_dict
from pgt_check.config.load import load_config_file as _read_config_file
from pgt_check.config.measure import (
    EdgeConfig,
    EnhanceConfig,
    HomographyConfig,
    InputConfig,
    MatchConfig,
    PoseConfig,
    RenderConfig,
)
from pgt_check.errors import ConfigError

__all__ = ["ACTION_KEYS", "MEASUREMENT_SECTIONS", "PRESETS", "RunConfig", "load_config_file",
           "moved_to_sections"]

logger = logging.getLogger(__name__)

#: one-shot actions of a run, not settings: given on each command line (``--resume``,
#: ``--overwrite``), never replayed from a config file (a run's config.json once stored them)
ACTION_KEYS = ("resume", "overwrite")


def load_config_file(path: str | Path) -> dict[str, Any]:
    """A JSON or TOML config file as settings (``config.load.load_config_file``), without the
    one-shot actions of ``ACTION_KEYS``: replaying a run's config.json must neither discard
    its stored records (``overwrite``) nor fail as replay-and-resume (``resume``). An action
    set in the file is ignored with a WARNING naming the option to pass instead. Settings of
    the older layout are moved to their sections (``moved_to_sections``)."""
    data = moved_to_sections(_read_config_file(path))
    for key in ACTION_KEYS:
        if key in data and data.pop(key) is not False:
            logger.warning("%s: %r is a one-shot action, not a setting: ignored (pass --%s "
                           "on the command line)", path, key, key)
    return data


#: config sections whose change invalidates stored per-frame measurements
MEASUREMENT_SECTIONS = ("input", "render", "match", "homography", "enhance", "edges", "pose")


#: a Dask scheduler address: [tcp|tls|ucx|ws|wss://]host[:port], or inproc://...
_SCHEDULER = re.compile(
    r"(?:(?:tcp|tls|ucx|ws|wss)://)?(?:\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+)(?::\d{1,5})?"
    r"|inproc://\S+"
)


def _check_scheduler(address: str | None) -> None:
    """ValueError unless ``address`` (None = a local cluster) looks like a scheduler address."""
    if address is None:
        return
    m = _SCHEDULER.fullmatch(address)
    port = address.rsplit(":", 1)[-1] if m and not address.startswith("inproc") else ""
    if m is None or (port.isdigit() and not 0 < int(port) < 65536):
        raise ValueError(
            f"scheduler: expected a Dask scheduler address such as tcp://host:8786; got "
            f"{address!r}"
        )


@dataclass(frozen=True)
class RunConfig:
    input: InputConfig = field(default_factory=InputConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    match: MatchConfig = field(default_factory=MatchConfig)
    homography: HomographyConfig = field(default_factory=HomographyConfig)
    enhance: EnhanceConfig = field(default_factory=EnhanceConfig)
    edges: EdgeConfig = field(default_factory=EdgeConfig)
    pose: PoseConfig = field(default_factory=PoseConfig)
    verdict: VerdictConfig = field(default_factory=VerdictConfig)
    gate: GateConfig = field(default_factory=GateConfig)
    run_checks: RunChecksConfig = field(default_factory=RunChecksConfig)
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
    #: OpenCV and BLAS threads per process (within a frame); None (0 in a file or on the
    #: command line) = the libraries' defaults, every core. 1: see pgt_check/threads.py
    threads: int | None = 1
    #: address of an existing Dask scheduler (tcp://host:8786); None = start a LocalCluster
    scheduler: str | None = None
    #: keep frames already measured with the same settings in ``out``, recompute the others
    resume: bool = False
    #: discard the per-frame records already in ``out`` and start fresh
    overwrite: bool = False
    #: times a frame whose worker process died is run again before it is UNVERIFIABLE
    retries: int = 1
    #: after the verdicts, measure this many PASS frames again at poses moved by known amounts
    #: around the stated detection limits (0 = off; ``pgt_check.verdict.self_test``)
    self_test: int = 0

    def __post_init__(self) -> None:
        _check_range("workers", self.workers, 1, 4096)
        if self.threads == 0:  # 0 = the libraries' defaults (as match.resize_max 0 = original)
            object.__setattr__(self, "threads", None)
        _check_range("threads", self.threads, 1, 4096)
        _check_range("retries", self.retries, 0, 100)
        _check_range("self_test", self.self_test, 0, 100_000)
        _check_range("limit", self.limit, 1)
        _check_range("report_details", self.report_details, 0)
        _check_scheduler(self.scheduler)
        if not isinstance(self.out, str) or not self.out.strip():
            raise ValueError(f"out: expected an output directory, got {self.out!r} (an empty "
                             "path would write into the current directory)")
        if self.resume and self.overwrite:
            raise ValueError("resume and overwrite exclude each other: pick one")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunConfig:
        """Strict: unknown keys and mistyped values raise ConfigError. Settings of the older
        layout (``MOVED_KEYS``: config.json of older runs) are read at their new place."""
        return from_dict(cls, moved_to_sections(data))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def settings_dict(self) -> dict[str, Any]:
        """``to_dict`` without the one-shot actions (``ACTION_KEYS``): what config.json
        stores, so that ``--config OUT/config.json`` replays the settings only."""
        return {k: v for k, v in self.to_dict().items() if k not in ACTION_KEYS}

    def measurement_settings(self) -> dict[str, Any]:
        """Every setting that changes a per-frame measurement.

        The measurement sections, plus the verdict settings the measurement stage reads:
        ``min_coverage`` (frames below it are not matched) and, with ``enhance.mode = auto``,
        the threshold (the auto-enhance decision depends on it).
        """
        d = self.to_dict()
        keep: dict[str, Any] = {k: d[k] for k in MEASUREMENT_SECTIONS}
        used: dict[str, float | None] = {"min_coverage": self.verdict.min_coverage}
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


def moved_to_sections(data: dict[str, Any]) -> dict[str, Any]:
    """``data`` with settings of the older layout (``MOVED_KEYS``) moved to their sections
    (logged); a setting given at both places is a ConfigError."""
    if not isinstance(data, dict):
        return data
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in data.items()}
    for (old_sec, old_key), (new_sec, new_key) in MOVED_KEYS.items():
        sec = out.get(old_sec)
        if not isinstance(sec, dict) or old_key not in sec:
            continue
        target = out.setdefault(new_sec, {})
        if not isinstance(target, dict):
            continue  # from_dict names the mistyped section
        if new_key in target:
            raise ConfigError(f"{old_sec}.{old_key} and {new_sec}.{new_key} are the same "
                              f"setting (older and current layout): give it once, as "
                              f"{new_sec}.{new_key}")
        target[new_key] = sec.pop(old_key)
        logger.info("config: %s.%s is read as %s.%s (older layout)", old_sec, old_key,
                    new_sec, new_key)
    return out


#: Named presets (merged under the CLI options and any --config file). The points were chosen
#: from the error-vs-runtime Pareto front in reports/error_vs_runtime.md.
PRESETS: dict[str, dict[str, Any]] = {
    "fast": {
        "match": {"method": "sift", "resize_max": 320},
        "enhance": {"mode": "never"},
        "pose": {"enabled": False},
        # the edge path (where the raw one is not decisive) at 640 px: about half the cost of
        # the default 1024 on large photos; shared errors of a few px are still flagged,
        # their size underestimated (reports/shared_errors.md, Presets)
        # and no cross-validated refit of the frames the fixed model does not pass (on a
        # failing run that is every frame)
        "edges": {"resize_max": 640, "select_model": "never"},
    },
    "balanced": {
        "match": {"method": "sift", "resize_max": 320},
        "enhance": {"mode": "auto", "method": "reproject"},
    },
    "accurate": {
        "match": {"method": "xfeat", "resize_max": 640},
        "enhance": {"mode": "auto", "method": "reproject"},
        # the edge path on every frame: XFeat's matches are decisive on coloured meshes, and a
        # mesh coloured with the poses under test hides their shared error from texture
        # matches (reports/pipeline_timing.md, "The XFeat lever")
        "edges": {"mode": "always"},
    },
}


