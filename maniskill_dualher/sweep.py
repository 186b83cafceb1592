"""``python -m maniskill_dualher.sweep``: the entry point; the sweep lives in ``experiment/sweep.py``."""
import sys

from maniskill_dualher.experiment.sweep import main

if __name__ == "__main__":
    sys.exit(main())
