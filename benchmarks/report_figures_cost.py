"""What the report's figures cost: CPU seconds of the "report files" stage
(``pgt_check.report.outputs:write_outputs``: frames.csv, summary.json, report.html, junit.xml and
the five plots) on a synthetic table of judged rows, and of the plots alone, at 30 and 1,000
frames; and the import of matplotlib (the plotting library, imported only when the report is
written) in a fresh process.

Each measurement runs in a fresh Python process (``--child``), as in a run: the first
``write_outputs`` of a process pays the lazy imports (jinja2, matplotlib), a second one in the
same process does not. CPU is the process's (all threads), from ``time.process_time``. The rows
are the report tests' synthetic ones (``tests/pgt_check/report/report_testdata.py``: PASS / FAIL
/ UNVERIFIABLE frames, raw and enhanced paths, camera centres, a drift curve), so every figure is
drawn. Prints a Markdown table (medians over ``--repeats`` processes).

    python benchmarks/report_figures_cost.py [--frames 30,1000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _child_import() -> dict[str, float]:
    t0 = time.process_time()
    import matplotlib.backends.backend_svg  # noqa: F401  (imported by savefig(format="svg"))
    import matplotlib.figure  # noqa: F401  (what plots.py imports)

    return {"import_matplotlib_s": time.process_time() - t0}


def _child_report(n: int) -> dict[str, float]:
    sys.path.insert(0, str(REPO / "tests" / "pgt_check" / "report"))
    from report_testdata import judged, shared_errors_summary, synthetic_measurements

    from pgt_check.config import RunConfig
    from pgt_check.report.outputs import write_outputs
    from pgt_check.report.plots import write_plots

    config = RunConfig.from_dict({"input": {"trajectory": "t.txt", "mesh": "m.ply"}})
    rows = judged(synthetic_measurements(n, enhanced=True, hostile=False), config)
    shared = shared_errors_summary(n)
    del shared["calibration"]  # the figures do not show it; no calibrated_sensors.txt
    extra = {"shared_errors": shared}
    res: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for key in ("report_files_first_s", "report_files_again_s"):
            out = Path(tmp) / key
            t0 = time.process_time()
            summary = write_outputs(out, rows, config, extra=extra)
            res[key] = time.process_time() - t0
        t0 = time.process_time()
        plots = write_plots(rows, summary, Path(tmp) / "plots")
        res["plots_again_s"] = time.process_time() - t0
        res["n_plots"] = len(plots)
        res["plots_kib"] = sum((Path(tmp) / "plots" / p["path"]).stat().st_size
                               for p in plots) / 1024
    return res


def _run_child(*args: str) -> dict[str, float]:
    out = subprocess.run([sys.executable, __file__, "--child", *args], cwd=REPO,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", default="30,1000")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        kind = args.child[0]
        res = _child_import() if kind == "import" else _child_report(int(args.child[1]))
        print(json.dumps(res))
        return
    med = statistics.median
    imports = [_run_child("import")["import_matplotlib_s"] for _ in range(args.repeats)]
    print(f"import matplotlib.figure + backend_svg, fresh process: CPU {med(imports):.2f} s "
          f"(median of {args.repeats}: {', '.join(f'{v:.2f}' for v in imports)})\n")
    print("| frames | report files, first in the process (CPU s) | report files again (CPU s) "
          "| plots alone, again (CPU s) | plots | plot files (KiB) |")
    print("|---|---|---|---|---|---|")
    for n in (int(v) for v in args.frames.split(",")):
        runs = [_run_child("report", str(n)) for _ in range(args.repeats)]
        col = {k: med(r[k] for r in runs) for k in runs[0]}
        print(f"| {n} | {col['report_files_first_s']:.2f} | {col['report_files_again_s']:.2f} "
              f"| {col['plots_again_s']:.2f} | {int(col['n_plots'])} | {col['plots_kib']:.0f} |")


if __name__ == "__main__":
    main()
