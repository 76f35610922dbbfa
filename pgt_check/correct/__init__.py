"""The correction stage of a run (after the verdicts, before the report): what the verdicts'
evidence says the poses should have been.

* ``registration``: when the run-level registration check fails, its estimate refined by
  measuring the frames again at the poses it corrects (``run_checks.refine_rounds``);
  ``registration_refined.json``, ``registered_trajectory.txt``.
* ``calibration``: a significant calibration estimate written exactly, as a LaMAR session
  with a rig (``calibrated/``).
* ``frames``: corrected poses of the chosen frames (``correct.frames``: FAIL or all);
  ``corrected_trajectory.txt``, ``bad_frames.txt``.
* ``pose``: one frame's pose refined by render -> raw match -> PnP rounds (``Correction``,
  ``refine_pose``) and ``corrections.json`` (the correction columns of the rows).
"""
