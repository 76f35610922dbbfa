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
Input errors raise ``pgt_check.errors.InputError``.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pgt_check.config import RunConfig, merge
from pgt_check.errors import InputError
from pgt_check.types import Trajectory

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd

__all__ = ["check", "frames_dataframe"]


def frames_dataframe(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """The per-frame rows as a DataFrame, columns in frames.csv order (then any others)."""
    import pandas as pd

    from pgt_check.report.outputs import FRAME_COLUMNS

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
    the output folder.
    """
    from pgt_check.config import load_config_file
    from pgt_check.runner import load_trajectory, run_trajectory

    if isinstance(config, RunConfig):
        base = config.to_dict()
    elif isinstance(config, (str, Path)):
        base = load_config_file(config)
    else:
        base = dict(config or {})
    inp: dict[str, Any] = {"mesh": str(mesh)}
    if not isinstance(trajectory, Trajectory):
        inp["trajectory"] = str(trajectory)
    elif trajectory.source:
        inp["trajectory"] = trajectory.source
    data = merge(merge(base, {"input": inp}), settings)
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
    summary = run_trajectory(traj, cfg, t0=t0)
    df = frames_dataframe(_rows(Path(cfg.out), cfg))  # the stored rows, as frames.csv has them
    df.attrs["summary"] = summary
    df.attrs["out"] = str(cfg.out)
    return df


def _rows(out: Path, cfg: RunConfig) -> list[dict[str, Any]]:
    """The judged rows of a finished run directory (verdicts + correction columns)."""
    from pgt_check.measure.correct import add_correction_columns, load_corrections
    from pgt_check.report.cli import load_run
    from pgt_check.verdict import apply_verdicts

    records, _ = load_run(out)
    return add_correction_columns(apply_verdicts(records, cfg), load_corrections(out))
