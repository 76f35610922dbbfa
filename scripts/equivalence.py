"""Behaviour kept across a refactor: run pgt-check on the sample scene, the boxes scene and 20
shared 7-Scenes frames, then compare frames.csv and summary.json of two such runs (timings,
versions and run folders aside).

    python scripts/equivalence.py run OUT_DIR      # with the code on PYTHONPATH
    python scripts/equivalence.py diff BEFORE AFTER

Exit code of ``diff``: 0 identical, 1 differences (listed)."""

from __future__ import annotations

import csv
import json
import math
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the checkout's pgt_check, installed or not
#: summary.json keys that change between identical runs: clocks, package versions, and the
#: fingerprint (it keys the record store by settings and input paths: another checkout differs)
VOLATILE_KEYS = {"timing", "versions", "version", "elapsed_s", "out", "wall_s", "wall_time_s",
                 "time_s", "layout", "fingerprint"}


#: floats of summary.json equal to this relative tolerance count as equal: the edge path's
#: least-squares refinement varies in the last digits between identical runs under CPU load
#: (thread scheduling of the reductions); frames.csv (6 significant digits) is compared exactly
REL_TOL = 1e-9


def _cases() -> dict[str, list[str]]:
    data = Path(os.environ.get("PGT_SHARED_DATA", ROOT.parent / "shared" / "data"))
    s, b, k = ROOT / "sample_data" / "scene", ROOT / "sample_data" / "boxes", \
        data / "7scenes_redkitchen"
    return {
        "sample": [str(s / "trajectories.txt"), "--mesh", str(s / "mesh.glb")],
        "boxes": [str(b / "trajectories.txt"), "--mesh", str(b / "boxes.ply")],
        "7s": [str(k / "trajectories.txt"), "--mesh", str(k / "mesh.ply"), "--limit", "20"],
    }


def run(out: Path) -> None:
    from pgt_check.cli import main

    for name, args in _cases().items():
        rc = main([*args, "--out", str(out / name), "-q"])
        (out / name / "exit_code.txt").write_text(f"{rc}\n")


def _timing_columns(header: list[str]) -> set[str]:
    from pgt_check.report.outputs import STAGES

    return {c for c in header if c in STAGES or c.endswith("_ms") or c.endswith("_s")}


def _strip(value, path=""):
    if path == ".settings" and isinstance(value, dict):
        from pgt_check.config import moved_to_sections

        value = moved_to_sections(value)  # an older layout's settings, at their new place
    if isinstance(value, dict):
        return {k: _strip(v, f"{path}.{k}") for k, v in value.items() if k not in VOLATILE_KEYS}
    if isinstance(value, list):
        return [_strip(v, path) for v in value]
    if isinstance(value, str) and ("/tmp/" in value or str(ROOT) in value):
        return "<path>"
    return value


def _diff_json(a, b, path="") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                out.append(f"{path}.{k}: only in {'after' if k in b else 'before'}")
            else:
                out += _diff_json(a[k], b[k], f"{path}.{k}")
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True)) for d in _diff_json(x, y, f"{path}[{i}]")]
    if isinstance(a, float) and isinstance(b, float) and math.isclose(a, b, rel_tol=REL_TOL):
        return []
    return [] if a == b else [f"{path}: {a!r} -> {b!r}"]


def diff(before: Path, after: Path) -> int:
    problems = []
    for name in _cases():
        a, b = before / name, after / name
        for f in ("exit_code.txt",):
            if (a / f).read_text() != (b / f).read_text():
                problems.append(f"{name}/{f} differs")
        with open(a / "frames.csv", newline="") as fa, open(b / "frames.csv", newline="") as fb:
            ra, rb = list(csv.DictReader(fa)), list(csv.DictReader(fb))
        if not ra or not rb or list(ra[0]) != list(rb[0]):
            problems.append(f"{name}/frames.csv: columns differ")
        skip = _timing_columns(list(ra[0])) if ra else set()
        for x, y in zip(ra, rb, strict=False):
            d = {k: (v, y.get(k)) for k, v in x.items() if k not in skip and y.get(k) != v}
            if d:
                problems.append(f"{name}/frames.csv {x['frame_id']}: {d}")
        if len(ra) != len(rb):
            problems.append(f"{name}/frames.csv: {len(ra)} vs {len(rb)} rows")
        sa = _strip(json.loads((a / "summary.json").read_text()))
        sb = _strip(json.loads((b / "summary.json").read_text()))
        problems += [f"{name}/summary.json {d}" for d in _diff_json(sa, sb)]
    for p in problems:
        print(p)
    print("identical" if not problems else f"{len(problems)} differences")
    return 1 if problems else 0


if __name__ == "__main__":
    if len(sys.argv) != 3 + (sys.argv[1:2] == ["diff"]):
        sys.exit(__doc__)
    if sys.argv[1] == "run":
        run(Path(sys.argv[2]))
    else:
        sys.exit(diff(Path(sys.argv[2]), Path(sys.argv[3])))
