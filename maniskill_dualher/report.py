"""``python -m maniskill_dualher.report``: the entry point; the report lives in ``analysis/report.py``."""
import sys

from maniskill_dualher.analysis.report import build_report, main  # noqa: F401

if __name__ == "__main__":
    sys.exit(main())
