import os

import pytest

# Keep tests deterministic and polite on a 2-core machine.
os.environ.setdefault("OMP_NUM_THREADS", "1")


# Module fixtures that run a sweep every test of their file reads. With `--dist loadgroup` (CI's and the README's
# test command) the tests that take one run in one xdist process, so the sweep is built once, not in both.
SHARED_SWEEPS = {"smoke_local", "chain_sweep", "reference"}


@pytest.hookimpl(tryfirst=True)   # before xdist's own, which reads the marks into the tests' ids
def pytest_collection_modifyitems(config, items):
    for item in items:
        shared = sorted(SHARED_SWEEPS & set(getattr(item, "fixturenames", ())))
        if shared:
            item.add_marker(pytest.mark.xdist_group(f"{item.module.__name__}:{shared[0]}"))
