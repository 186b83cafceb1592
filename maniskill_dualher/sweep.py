"""``python -m maniskill_dualher.sweep``: the entry point. The sweep lives in ``experiment/sweep.py``; here it
is handed what its workers run (the training driver, ``train.train_runs``) and what it builds at the end (the
report), so that the experiment layer imports neither. Both import where they are called: ``--help`` and
``--dry-run`` load no simulator, and a pool or Ray worker unpickles ``train_runs`` below by its name."""
import sys

from maniskill_dualher.experiment import sweep as _sweep


def train_runs(jobs, **kw):
    """``train.train_runs``, imported in the process that trains."""
    from maniskill_dualher.train import train_runs as run
    return run(jobs, **kw)


def build_report(out):
    """``analysis.report.build_report``."""
    from maniskill_dualher.analysis.report import build_report as build
    return build(out)


def main(argv=None) -> int:
    return _sweep.main(argv, train=train_runs, report=build_report)


if __name__ == "__main__":
    sys.exit(main())
