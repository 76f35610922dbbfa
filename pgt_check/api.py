"""Python API: ``check(trajectory | path, mesh, **settings) -> pandas.DataFrame``.

>>> from pgt_check.api import check
>>> df = check("sample_data/scene/trajectories.txt", "sample_data/scene/mesh.glb", limit=3,
...            match={"method": "orb"})                                     # doctest: +SKIP
>>> df[["frame_id", "verdict", "corner_error_px"]]                          # doctest: +SKIP
>>> df.attrs["summary"]["gate"]                                             # doctest: +SKIP

``trajectory``: a path (read with ``pgt_check.io.read_trajectory``; ``format``, ``images``,
``camera``, ``sensors`` go in the ``input`` section) or an in-memory
``pgt_check.types.Trajectory`` (e.g. poses under test from your own pipeline). ``settings``:
top-level ``RunConfig`` keys; sections as dicts (``verdict={"threshold_px": 5}``), e.g.
``limit``, ``out``, ``correct={"frames": "none"}``. Without ``out`` the run writes into a new
temporary folder (``df.attrs["out"]``: frames.csv, report.html, corrected_trajectory.txt ...).

An ``out`` of an earlier call: the frames whose settings and inputs are unchanged are reused and
every other frame is measured again (the CLI's ``--resume``, the default here): a changed mesh,
pose, photo or setting never returns the old results. ``overwrite=True`` discards the stored
measurements and measures every frame again; ``resume=False`` refuses (InputError) an ``out``
that holds measurements of other settings or inputs, as the CLI does without ``--resume``.

Errors: every input problem raises ``pgt_check.errors.InputError`` with a one-line message that
names the argument, file or setting: an argument of the wrong type (``config=5``, a
``trajectory`` that is neither a path nor a ``Trajectory``), an unknown or mistyped setting
(``ConfigError``), a malformed file (``FormatError``) and a checker that cannot be built here
(``SetupError``, also when it fails in a worker process) are all InputErrors, never a raw
``TypeError`` / ``AttributeError``.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pgt_check.config import RunConfig, merge
from pgt_check.errors import InputError
from pgt_check.types import Trajectory

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd

__all__ = ["check", "frames_dataframe"]


def _type_name(value: Any) -> str:
    return type(value).__name__


def _path_arg(name: str, value: Any) -> str:
    """``value`` as a path string; InputError naming ``name`` for anything but a non-empty
    ``str`` or ``os.PathLike``."""
    if isinstance(value, (str, os.PathLike)):
        text = os.fspath(value)
        if isinstance(text, str) and text:
            return text
    raise InputError(
        f"{name} must be a file path (str or os.PathLike); got {_type_name(value)} {value!r:.80}"
    )


def _base_settings(config: Any) -> dict[str, Any]:
    """The settings of ``check``'s ``config`` argument (RunConfig, mapping, config file)."""
    from pgt_check.config import load_config_file

    if config is None:
        return {}
    if isinstance(config, RunConfig):
        return config.to_dict()
    if isinstance(config, (str, os.PathLike)):
        return load_config_file(_path_arg("config", config))
    if isinstance(config, Mapping):
        bad = [k for k in config if not isinstance(k, str)]
        if bad:
            raise InputError(f"config: setting names must be strings; got {bad[0]!r}")
        return _plain_paths(config)
    raise InputError(
        "config must be a RunConfig, a dict of settings or a config file path; got "
        f"{_type_name(config)} {config!r:.80}"
    )


def _plain_paths(value: Any) -> Any:
    """``value`` with every ``os.PathLike`` (in nested dicts too) as its path string: settings
    such as ``out=Path(...)`` or ``input={"images": Path(...)}`` are accepted like strings."""
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, Mapping):
        return {k: _plain_paths(v) for k, v in value.items()}
    return value


def frames_dataframe(rows: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """The per-frame rows as a DataFrame, columns in frames.csv order (then any others).

    InputError unless ``rows`` is a list (or other sequence) of mappings."""
    import pandas as pd

    from pgt_check.report.outputs import FRAME_COLUMNS

    if isinstance(rows, (str, bytes)) or not isinstance(rows, Sequence):
        raise InputError(f"rows must be a list of per-frame dicts; got {_type_name(rows)}")
    for i, row in enumerate(rows):
        if not isinstance(row, Mapping):
            raise InputError(f"rows[{i}] must be a dict of frame columns; got {_type_name(row)}")
    df = pd.DataFrame(rows)
    cols = [c for c in FRAME_COLUMNS if c in df.columns]
    cols += [c for c in df.columns if c not in cols]
    return df.reindex(columns=cols)


def check(
    trajectory: Trajectory | str | Path,
    mesh: str | Path,
    *,
    config: RunConfig | dict[str, Any] | str | Path | None = None,
    **settings: Any,
) -> pd.DataFrame:
    """Check every frame of ``trajectory`` against ``mesh``; one DataFrame row per frame.

    ``config``: a base RunConfig, dict or config file (``settings`` win over it). The frames.csv
    columns are the DataFrame's; ``df.attrs["summary"]`` is summary.json, ``df.attrs["out"]``
    the output folder. Raises InputError (see the module docstring) for any input problem.
    """
    from pgt_check.report.outputs import read_summary
    from pgt_check.runner import load_trajectory, run_trajectory

    base = _base_settings(config)
    inp: dict[str, Any] = {"mesh": _path_arg("mesh", mesh)}
    if not isinstance(trajectory, Trajectory):
        if not isinstance(trajectory, (str, os.PathLike)):
            raise InputError(
                "trajectory must be a pose file path (str or os.PathLike) or a "
                f"pgt_check.types.Trajectory; got {_type_name(trajectory)} {trajectory!r:.80}"
            )
        inp["trajectory"] = _path_arg("trajectory", trajectory)
    elif trajectory.source:
        inp["trajectory"] = trajectory.source
    settings = _plain_paths(settings)
    data = merge(merge(base, {"input": inp}), settings)
    explicit = "resume" in settings or (not isinstance(config, RunConfig) and "resume" in base)
    if not explicit and not data.get("overwrite"):
        data["resume"] = True  # changed inputs are measured again (module docstring)
    if "out" not in settings and "out" not in base:
        data["out"] = tempfile.mkdtemp(prefix="pgt-check-")
    cfg = RunConfig.from_dict(data)
    t0 = time.perf_counter()
    if isinstance(trajectory, Trajectory):
        if len(trajectory) == 0:
            raise InputError("the trajectory has no frames")
        if not Path(cfg.input.mesh).is_file():
            raise InputError(f"mesh not found: {cfg.input.mesh}")
        traj = trajectory
    else:
        traj = load_trajectory(cfg)
    # the CLI's own path: the same content keys decide what ``out`` may reuse
    # (a checker that cannot be built, here or in a worker, raises SetupError: an InputError)
    run_trajectory(traj, cfg, t0=t0)  # its outcome is written to cfg.out
    df = frames_dataframe(_rows(Path(cfg.out), cfg))  # the stored rows, as frames.csv has them
    df.attrs["summary"] = read_summary(Path(cfg.out))
    df.attrs["out"] = str(cfg.out)
    return df


def _rows(out: Path, cfg: RunConfig) -> list[dict[str, Any]]:
    """The judged rows of a finished run directory (verdicts + correction columns): the
    stored measurements judged again with ``cfg`` (``rejudge.rejudge``, as ``pgt-check
    report`` does)."""
    from pgt_check.rejudge import rejudge

    return rejudge(out, cfg).result.rows()
