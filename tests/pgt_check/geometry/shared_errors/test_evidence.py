"""``FrameEvidence`` (``geometry/shared_errors/evidence.py``): JSON round trip, and the three
estimators on the read-back evidence within a CPU-time budget."""

from __future__ import annotations

import json
import time

import numpy as np

from pgt_check.geometry.shared_errors import (
    FrameEvidence,
    estimate_calibration,
    estimate_drift,
    estimate_registration,
)
from tests.pgt_check.geometry.shared_errors.synthetic import (
    make_evidence,
    similarity,
)


def test_frame_evidence_json_round_trip_and_speed():
    ev = make_evidence(1, world_error=lambda i: similarity(1.0, (0, 0, 1), (0.05, 0, 0)))
    back = [FrameEvidence.from_json(json.loads(json.dumps(e.to_json()))) for e in ev]
    np.testing.assert_allclose(back[3].pts3d, ev[3].pts3d, atol=1e-5)
    np.testing.assert_allclose(back[3].pts2d, ev[3].pts2d, atol=1e-3)
    t0 = time.process_time()  # CPU time: robust to other jobs on a shared machine
    reg = estimate_registration(back)
    cal = estimate_calibration(back)
    drift = estimate_drift(back)
    assert time.process_time() - t0 < 5.0  # ~0.7 s on one core
    assert reg.success and drift.success and cal["cam"].success
    json.dumps(reg.to_json()), json.dumps(drift.to_json()), json.dumps(cal["cam"].to_json())
