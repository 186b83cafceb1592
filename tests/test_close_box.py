"""CloseBox-v1 specifics (what both hinge tasks must show is in tests/test_hinged.py; the shared task contract
in tests/test_tasks.py)."""
import itertools

import numpy as np
import pytest

import maniskill_dualher.tasks  # noqa: F401  (registers the tasks)
from maniskill_dualher.tasks.close_box import CloseBoxEnv
from maniskill_dualher.tasks.solvers import make_solver

from articulated import env_fixture, goals_at_angle, set_state

LO_ANGLE, HI_ANGLE = CloseBoxEnv.INIT_ANGLE_RANGE


env = env_fixture("CloseBox-v1")


@pytest.mark.parametrize("angle", [0.03, 0.7, HI_ANGLE])
def test_free_edge_rises_with_the_lid(env, angle):
    """Horizontal hinge on the robot's side: opening lifts the free edge out of the box top plane."""
    base = env.unwrapped
    _, ag, dg = goals_at_angle(env, angle)
    assert float(ag[2] - dg[2]) == pytest.approx(base.LID_LENGTH * np.sin(angle), abs=2e-5)


# Box poses (centre x, centre y, yaw) at the corners of the documented ranges.
CORNERS = list(itertools.product(CloseBoxEnv.CENTER_X_RANGE, CloseBoxEnv.CENTER_Y_RANGE, CloseBoxEnv.YAW_RANGE))


def _solve_from(env, seed, center, yaw, angle):
    env.reset(seed=seed)
    set_state(env, angle=angle, center=center, yaw=yaw)
    solver = make_solver(env)
    for _ in range(150):
        _, _, _, trunc, info = env.step(solver.act(None))
        if bool(info["success"][0]) or bool(trunc[0]):
            break
    return bool(info["success"][0])


def test_solver_reaches_all_range_corners_both_angles(env):
    """Reachability: the scripted push succeeds at every corner of the documented ranges (~15 s)."""
    fails = [(c, a) for c in CORNERS for a in (LO_ANGLE, HI_ANGLE)
             if not _solve_from(env, 6, c[:2], c[2], a)]
    assert not fails
