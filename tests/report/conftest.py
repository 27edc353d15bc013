"""The report room's run-directory fixtures (defined in test_report.py), for the other test modules here."""

from tests.report.test_report import headline_run, run_dir, study_dir  # noqa: F401
