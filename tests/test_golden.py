"""bench/golden.py reads the checkpoints and policies its runs write (on this tree or an older one) without
unpickling code: tensors and numpy arrays load, any other global is refused before it runs."""
from pathlib import Path

import numpy as np
import pytest
import torch

from bench_cli import load_bench


class _WritesAFile:
    def __init__(self, path):
        self.path = str(path)

    def __reduce__(self):
        return (Path(self.path).write_text, ("ran",))


def test_golden_loads_tensors_and_an_older_trees_numpy_arrays(tmp_path):
    golden = load_bench("golden.py")
    state = {"agent": {"w": torch.arange(3.0)}, "replay": np.arange(4, dtype=np.float32),
             "flags": np.array([True, False]), "step": np.int64(7)}
    torch.save(state, tmp_path / "old.pt")
    back = golden.load_tensors(tmp_path / "old.pt")
    assert torch.equal(back["agent"]["w"], state["agent"]["w"]) and back["step"] == 7
    assert back["replay"].dtype == np.float32 and np.array_equal(back["replay"], state["replay"])
    assert np.array_equal(back["flags"], state["flags"])


def test_golden_refuses_a_file_that_would_run_code(tmp_path):
    golden = load_bench("golden.py")
    marker = tmp_path / "marker"
    torch.save({"agent": _WritesAFile(marker)}, tmp_path / "bad.pt")
    with pytest.raises(ValueError, match="not tensors and numpy arrays; not loaded"):
        golden.load_tensors(tmp_path / "bad.pt")
    assert not marker.exists()
