"""CloseBox-v1 physics and task-definition tests (the shared contract is in tests/test_tasks.py)."""
import itertools

import gymnasium as gym
import numpy as np
import pytest
import torch

import maniskill_dualher  # noqa: F401  (registers the tasks)
from tasks.close_box import CloseBoxEnv
from tasks.common import OBS_SLICES, split_goal_obs
from tasks.solvers import make_solver

from articulated import robot_contact_force, set_articulation_state

LO_ANGLE, HI_ANGLE = CloseBoxEnv.INIT_ANGLE_RANGE


@pytest.fixture(scope="module")
def env():
    e = gym.make("CloseBox-v1", control_mode="pd_joint_delta_pos")
    yield e
    e.close()


def lid_angle(env) -> float:
    return float(env.unwrapped.box.qpos[0, 0])


def set_state(env, angle=None, center=None, yaw=None):
    """Overwrite the lid angle and/or box pose of the current (CPU, single) episode."""
    base = env.unwrapped
    set_articulation_state(base.box, base.BOX_LIFT, angle, center, yaw)
    if center is not None:
        base._refresh_goal_cache()


def robot_lid_contact(env) -> float:
    """Largest contact force between any robot link and the lid or box (N)."""
    return robot_contact_force(env, env.unwrapped.box)


def test_hinge_parameters_applied(env):
    base = env.unwrapped
    env.reset(seed=0)
    assert float(base.hinge.friction[0]) == pytest.approx(base.HINGE_FRICTION)  # set after build
    assert float(base.hinge.damping[0]) == pytest.approx(base.HINGE_DAMPING)
    torch.testing.assert_close(base.box.qlimits[0, 0], torch.tensor(base.HINGE_LIMITS, dtype=torch.float32))


@pytest.mark.parametrize("angle", [LO_ANGLE, HI_ANGLE, 0.15])
def test_idle_lid_holds_its_angle(env, angle):
    """Nothing touches the lid (robot holds its start pose): gravity must not shut it."""
    env.reset(seed=1)
    set_state(env, angle=angle)
    zero = torch.zeros(env.action_space.shape)
    start = lid_angle(env)
    for _ in range(100):
        _, _, _, _, info = env.step(zero)
        assert robot_lid_contact(env) == 0.0, "the robot must start clear of the box and lid"
    assert abs(lid_angle(env) - start) < 1e-3
    assert not bool(info["success"][0])


def test_solver_push_closes_lid_by_contact(env):
    """At the largest start angle the lid only moves while the robot touches it, and only shut."""
    obs, _ = env.reset(seed=2)
    set_state(env, angle=HI_ANGLE)
    solver = make_solver(env)
    angles, touching = [lid_angle(env)], []
    for _ in range(60):
        _, _, _, _, info = env.step(solver.act(None))
        angles.append(lid_angle(env))
        touching.append(robot_lid_contact(env) > 0.0)
        if bool(info["success"][0]):
            break
    angles = np.array(angles)
    assert bool(info["success"][0]) and angles[-1] < CloseBoxEnv.SUCCESS_ANGLE
    first_touch = touching.index(True)
    assert np.all(np.abs(angles[:first_touch + 1] - HI_ANGLE) < 1e-3), "lid moved before the robot touched it"
    assert np.all(np.diff(angles) < 1e-3), "the push must only close the lid"
    assert angles[0] - angles[-1] > 1.0


def test_lid_stays_closed_after_the_push(env):
    env.reset(seed=3)
    solver = make_solver(env)
    for t in range(150):
        _, _, _, trunc, info = env.step(solver.act(None))
        if bool(trunc[0]):
            break
    assert bool(info["success"][0]), f"lid angle {lid_angle(env):.3f} at the end of the episode"


def test_randomization_in_documented_ranges(env):
    base = env.unwrapped
    doc = CloseBoxEnv.__doc__
    for lo_hi in (base.CENTER_X_RANGE, base.CENTER_Y_RANGE, base.YAW_RANGE, base.INIT_ANGLE_RANGE):
        assert f"[{lo_hi[0]:.2f}, {lo_hi[1]:.2f}]" in doc.replace("[0.5, 1.3]", "[0.50, 1.30]")
    xs, ys, yaws, angles = [], [], [], []
    for seed in range(40):
        obs, info = env.reset(seed=seed)
        p, q = base.box.pose.p[0], base.box.pose.q[0]
        xs.append(float(p[0]))
        ys.append(float(p[1]))
        assert float(p[2]) == pytest.approx(base.BOX_LIFT, abs=1e-6)
        assert abs(float(q[1])) < 1e-6 and abs(float(q[2])) < 1e-6, "the box only turns about z"
        yaws.append(2 * float(torch.atan2(q[3], q[0])))
        angles.append(lid_angle(env))
        o = split_goal_obs(obs)[0][0]
        assert float(o[OBS_SLICES["joint_qpos"]][0]) == pytest.approx(angles[-1])
        torch.testing.assert_close(o[OBS_SLICES["object_pose"]], base.lid.pose.raw_pose[0])
    for vals, (lo, hi) in ((xs, base.CENTER_X_RANGE), (ys, base.CENTER_Y_RANGE), (yaws, base.YAW_RANGE),
                           (angles, base.INIT_ANGLE_RANGE)):
        vals = np.array(vals)
        assert vals.min() >= lo - 1e-5 and vals.max() <= hi + 1e-5
        assert vals.max() - vals.min() > 0.5 * (hi - lo), "the range should actually be used"


@pytest.mark.parametrize("angle", [0.0, 0.03, 0.0995, 0.1005, 0.2, 0.7, HI_ANGLE, 1.8])
def test_success_iff_free_edge_within_tolerance(env, angle):
    base = env.unwrapped
    env.reset(seed=4)
    set_state(env, angle=angle)
    info = base.evaluate()
    ag, dg = info["achieved_goal"][0], info["desired_goal"][0]
    dist = float(torch.linalg.norm(ag - dg))
    assert dist == pytest.approx(2 * base.LID_LENGTH * np.sin(angle / 2), abs=2e-5)  # chord of the free edge
    assert bool(info["success"][0]) == (dist < base.goal_tolerance) == (angle < base.SUCCESS_ANGLE)
    assert float(base.compute_reward(ag, dg)) == float(angle < base.SUCCESS_ANGLE)
    # the free edge leaves the box top plane upwards (hinge axis on the robot's side)
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
