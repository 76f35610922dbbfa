"""The stages a command runs, composed from the layers below (layer 6).

For a check run (``pgt_check.runner`` composes them): ``inputs`` (the prepare stage: trajectory,
preflight build of the checker, input hashes and the measurement fingerprint) and
``remeasure`` (the stages after the verdicts that measure frames again: correction,
self-test, separation). For the other commands: ``compare`` (``pgt-check compare``: two pose
sources compared) and ``enhance_folder`` (``pgt-check enhance``: a folder of renders enhanced).
"""
