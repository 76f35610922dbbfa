"""The per-frame bounds of the cached injections of ``benchmarks/accuracy.py`` judged again with
the current code (no measuring): does the 95 % bound cover the injected rotation / shift, and
what does the estimate give (estimate / injected), per frame, with the sources it rests on.

Needs the measurement cache of ``benchmarks/accuracy.py`` (/tmp/pgt-check-bench-accuracy) and
its reports/accuracy.json (the stated limits the injections were sized from).

    nice -n 10 python benchmarks/accuracy_rejudge.py > reports/accuracy_rejudged.txt
"""

from __future__ import annotations

import json

import accuracy as A
import numpy as np
from _common import REPORTS

from pgt_check.config import merge


def main() -> None:
    old = {r["dataset"]: r for r in json.loads((REPORTS / "accuracy.json").read_text())}
    for name, (traj, mesh, cfgd, truth0) in A.datasets(["sample", "7s", "castle"], 15).items():
        lim = old[name]["given"]["limits"]
        judged_cfg = cfgd
        if name == "7s":
            judged_cfg = merge(cfgd, {"run_checks": {
                "remove_calibration": False,
                "calibration_from": str(A.CACHE / "7s-given-summary.json")}})
        for k in (0.5, 1.0, 1.5, 2.0):
            copy, truth = A.per_frame_copy(traj, k * lim["frame_deg"], k * lim["frame_units"],
                                           set(truth0 or ()), seed=int(10 * k))
            cfg_k, ms = A.measure(copy, mesh, judged_cfg, f"{name}-frame-{k}-{len(traj.frames)}")
            rows, _, _ = A.judge(ms, cfg_k)
            byid = {r["frame_id"]: r for r in rows}
            line = []
            for kind, b, e in (("rot", "acc_rot_bound_deg", "acc_rot_deg"),
                               ("t", "acc_t_bound", "acc_t")):
                sel = [byid[f] for f, (kk, _) in truth.items()
                       if kk == kind and byid[f].get(b) is not None]
                cov = [r[b] >= truth[r["frame_id"]][1] for r in sel]
                ratio = [r[e] / truth[r["frame_id"]][1] for r in sel]
                src = [r["acc_evidence"].replace("+calibration removed", "") for r in sel]
                line.append(f"{kind}: covers {sum(cov)}/{len(cov)}, estimate/injected "
                            f"{np.round(ratio, 2).tolist()} on {src}")
            was = ", ".join(f"{p['kind']} {p['bound_covers'] * p['n_bounded']:.0f}/"
                            f"{p['n_bounded']}" for p in old[name]["per_frame"] if p["k"] == k)
            print(f"{name} {k}x: " + "; ".join(line) + f" (reports/accuracy.md: covers {was})",
                  flush=True)


if __name__ == "__main__":
    main()
