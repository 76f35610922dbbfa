"""The correction record: its frames.csv columns and the run folder's corrections file (what
``pgt-check report`` reads back)."""

from __future__ import annotations

import logging
import math

import numpy as np

from pgt_check.correct.correction import (
    CORRECTION_COLUMNS,
    Correction,
    load_corrections,
    save_corrections,
)
from pgt_check.output_layout import OUTPUTS


def test_corrections_round_trip_through_the_run_folder(tmp_path):
    pose = np.eye(4)
    pose[:3, 3] = (0.1, -0.2, 0.3)
    a = Correction("0/cam0", True, "", tuple(map(tuple, pose)), drot_deg=0.5, dt=0.01,
                   sigma_rot_deg=0.05, rounds=3, start="pnp_raw", applied=True,
                   steps=((0.4, 0.01), (0.1, 0.002)))
    b = Correction("1/cam0", False, "pnp_failed", sigma_rot_deg=math.inf, rounds=1)
    save_corrections(tmp_path, [a, b], fingerprint="abc")
    back = load_corrections(tmp_path)
    assert set(back) == {"0/cam0", "1/cam0"}
    assert back["0/cam0"] == a and np.allclose(back["0/cam0"].pose, pose)
    # a non-finite value is written as null (JSON has no inf) and read back as None
    assert back["1/cam0"].sigma_rot_deg is None and back["1/cam0"].pose is None
    assert back["1/cam0"].reason == "pnp_failed"


def test_row_has_exactly_the_correction_columns():
    row = Correction("f", True, "uncertain", drot_deg=1.0, rounds=2).row()
    assert tuple(row) == CORRECTION_COLUMNS
    assert row["corr_reason"] == "uncertain" and row["corr_applied"] is False


def test_a_missing_or_unreadable_file_gives_no_corrections(tmp_path, caplog):
    assert load_corrections(tmp_path) == {}
    (tmp_path / OUTPUTS.corrections).write_text('{"corrections": [{"no_id": 1}]}')
    with caplog.at_level(logging.WARNING):
        assert load_corrections(tmp_path) == {}
    assert "unreadable" in caplog.text
