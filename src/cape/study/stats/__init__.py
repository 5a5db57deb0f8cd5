"""The study's statistics (SPEC §10): verdicts from intervals over training draws, the
group-sequential test, and how often each errs (their calibration)."""
