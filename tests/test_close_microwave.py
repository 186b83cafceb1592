"""CloseMicrowave-v1 physics and task-definition tests (the shared contract is in tests/test_tasks.py)."""
import itertools

import gymnasium as gym
import numpy as np
import pytest
import torch

import maniskill_dualher  # noqa: F401  (registers the tasks)
from mani_skill.utils.geometry import rotation_conversions as rc
from tasks.close_microwave import CloseMicrowaveEnv
from tasks.common import OBS_SLICES, split_goal_obs
from tasks.solvers import make_solver

from articulated import robot_contact_force, set_articulation_state

LO_ANGLE, HI_ANGLE = CloseMicrowaveEnv.INIT_ANGLE_RANGE


@pytest.fixture(scope="module")
def env():
    e = gym.make("CloseMicrowave-v1", control_mode="pd_joint_delta_pos")
    yield e
    e.close()


def door_angle(env) -> float:
    return float(env.unwrapped.microwave.qpos[0, 0])


def set_state(env, angle=None, center=None, yaw=None):
    """Overwrite the door angle and/or microwave pose of the current (CPU, single) episode."""
    base = env.unwrapped
    set_articulation_state(base.microwave, base.BODY_LIFT, angle, center, yaw)
    if center is not None:
        base._refresh_goal_cache()


def robot_microwave_contact(env) -> float:
    """Largest contact force between any robot link and the microwave body or door (N)."""
    return robot_contact_force(env, env.unwrapped.microwave)


def tcp_door_coords(env):
    """TCP as (u, w): distance along the door from the hinge axis, and out from its outer face."""
    base = env.unwrapped
    door = base.door.pose
    local = rc.quaternion_apply(rc.quaternion_invert(door.q), base.agent.tcp.pose.p - door.p)
    return float(local[0, 1]), float(-local[0, 0])


def tcp_outside_swing(env, margin=0.02) -> bool:
    """The TCP is not between the door and the body: beside the hinge (u < 0) or outside the door face."""
    u, w = tcp_door_coords(env)
    return u < 0 or w > margin


def test_hinge_parameters_applied(env):
    base = env.unwrapped
    env.reset(seed=0)
    assert float(base.hinge.friction[0]) == pytest.approx(base.HINGE_FRICTION)  # set after build
    assert float(base.hinge.damping[0]) == pytest.approx(base.HINGE_DAMPING)
    torch.testing.assert_close(base.microwave.qlimits[0, 0], torch.tensor(base.HINGE_LIMITS, dtype=torch.float32))
    assert base.goal_tolerance == pytest.approx(2 * base.DOOR_LENGTH * np.sin(base.SUCCESS_ANGLE / 2))


@pytest.mark.parametrize("angle", [LO_ANGLE, HI_ANGLE, 0.15, 1.5])
def test_idle_door_holds_its_angle(env, angle):
    """Nothing touches the door (robot holds its start pose): it must neither swing nor drift."""
    env.reset(seed=1)
    set_state(env, angle=angle)
    zero = torch.zeros(env.action_space.shape)
    start = door_angle(env)
    for _ in range(100):
        _, _, _, _, info = env.step(zero)
        assert robot_microwave_contact(env) == 0.0, "the robot must start clear of the microwave"
    assert abs(door_angle(env) - start) < 1e-3
    assert not bool(info["success"][0])


def test_door_does_not_bounce_off_the_closed_limit(env):
    """Slammed shut at 3 rad/s from 0.02 rad, the door stops at the limit and stays there."""
    env.reset(seed=1)
    set_state(env, angle=0.02)
    env.unwrapped.microwave.set_qvel(torch.tensor([[-3.0]]))
    angles = []
    for _ in range(10):
        env.step(torch.zeros(env.action_space.shape))
        angles.append(door_angle(env))
    assert max(angles) < 1e-3 and min(angles) > -1e-3


def test_reset_starts_clear_outside_the_door(env):
    """At every reset the TCP is outside the door's swing (never between door and body); nothing touches."""
    for seed in range(20):
        env.reset(seed=seed)
        assert tcp_outside_swing(env), f"seed {seed}: TCP at (u, w) = {tcp_door_coords(env)} in the door frame"
        env.step(torch.zeros(env.action_space.shape))
        assert robot_microwave_contact(env) == 0.0, f"seed {seed}: robot touches the microwave at reset"


def test_solver_push_closes_door_by_contact(env):
    """At the largest start angle the door only moves while the robot touches it, and only shut."""
    env.reset(seed=2)
    set_state(env, angle=HI_ANGLE)
    solver = make_solver(env)
    angles, touching = [door_angle(env)], []
    for _ in range(100):
        _, _, _, _, info = env.step(solver.act(None))
        angles.append(door_angle(env))
        touching.append(robot_microwave_contact(env) > 0.0)
        if bool(info["success"][0]):
            break
    angles = np.array(angles)
    assert bool(info["success"][0]) and angles[-1] < CloseMicrowaveEnv.SUCCESS_ANGLE
    first_touch = touching.index(True)
    # Contacts are sampled at the end of each control step (5 sim steps); a first impact can end within
    # the step before, so allow the door to start moving one step before the first sampled contact.
    assert np.all(np.abs(angles[:first_touch] - HI_ANGLE) < 1e-3), "door moved before the robot touched it"
    assert sum(touching) >= 3, "the door is closed by sustained pushing, not one knock"
    assert np.all(np.diff(angles) < 1e-3), "the push must only close the door"
    assert angles[0] - angles[-1] > 1.0


def test_door_stays_closed_after_the_push(env):
    env.reset(seed=3)
    solver = make_solver(env)
    for _ in range(150):
        _, _, _, trunc, info = env.step(solver.act(None))
        if bool(trunc[0]):
            break
    assert bool(info["success"][0]), f"door angle {door_angle(env):.3f} at the end of the episode"
    assert door_angle(env) > -0.01, "the door must not pass through its closed limit"


def test_randomization_in_documented_ranges(env):
    base = env.unwrapped
    doc = CloseMicrowaveEnv.__doc__
    for lo, hi in (base.CENTER_X_RANGE, base.CENTER_Y_RANGE, base.YAW_RANGE, base.INIT_ANGLE_RANGE):
        assert f"[{lo:g}, {hi:g}]" in doc, f"range [{lo:g}, {hi:g}] is not documented"
    xs, ys, yaws, angles = [], [], [], []
    for seed in range(40):
        obs, info = env.reset(seed=seed)
        p, q = base.microwave.pose.p[0], base.microwave.pose.q[0]
        xs.append(float(p[0]))
        ys.append(float(p[1]))
        assert float(p[2]) == pytest.approx(base.BODY_LIFT, abs=1e-6), "the microwave stands on the table"
        assert abs(float(q[1])) < 1e-6 and abs(float(q[2])) < 1e-6, "the microwave only turns about z"
        yaws.append(2 * float(torch.atan2(q[3], q[0])))
        angles.append(door_angle(env))
        assert abs(float(base.microwave.qvel[0, 0])) < 1e-6, "the door starts at rest"
        o = split_goal_obs(obs)[0][0]
        assert float(o[OBS_SLICES["joint_qpos"]][0]) == pytest.approx(angles[-1])
        torch.testing.assert_close(o[OBS_SLICES["object_pose"]], base.door.pose.raw_pose[0])
    for vals, (lo, hi) in ((xs, base.CENTER_X_RANGE), (ys, base.CENTER_Y_RANGE), (yaws, base.YAW_RANGE),
                           (angles, base.INIT_ANGLE_RANGE)):
        vals = np.array(vals)
        assert vals.min() >= lo - 1e-5 and vals.max() <= hi + 1e-5
        assert vals.max() - vals.min() > 0.5 * (hi - lo), "the range should actually be used"


@pytest.mark.parametrize("angle", [0.0, 0.03, 0.0995, 0.1005, 0.2, 0.7, HI_ANGLE, 1.55])
def test_success_iff_free_edge_within_tolerance(env, angle):
    base = env.unwrapped
    env.reset(seed=4)
    set_state(env, angle=angle)
    info = base.evaluate()
    ag, dg = info["achieved_goal"][0], info["desired_goal"][0]
    dist = float(torch.linalg.norm(ag - dg))
    assert dist == pytest.approx(2 * base.DOOR_LENGTH * np.sin(angle / 2), abs=2e-5)  # chord of the free edge
    assert bool(info["success"][0]) == (dist < base.goal_tolerance) == (angle < base.SUCCESS_ANGLE)
    assert float(base.compute_reward(ag, dg)) == float(angle < base.SUCCESS_ANGLE)
    assert float(info["door_angle"][0]) == pytest.approx(angle, abs=1e-6)
    # vertical hinge: the free edge moves in the horizontal plane, towards the robot (-x in the body frame)
    assert float(ag[2] - dg[2]) == pytest.approx(0.0, abs=1e-5)
    yaw = 2 * float(torch.atan2(base.microwave.pose.q[0, 3], base.microwave.pose.q[0, 0]))
    front = torch.tensor([np.cos(yaw), np.sin(yaw), 0.0], dtype=torch.float32)  # body +x (away from the robot)
    assert float(torch.dot(ag - dg, front)) == pytest.approx(-base.DOOR_LENGTH * np.sin(angle), abs=2e-5)


def test_dense_reward_rewards_reaching_and_closing(env):
    base = env.unwrapped
    env.reset(seed=5)
    set_state(env, angle=0.8)
    info = base.evaluate()
    far = base._dense_shaping(info)
    assert 0.0 <= float(far[0]) < 0.5
    solver = make_solver(env)
    for _ in range(12):  # approach: the TCP nears the push point
        _, _, _, _, info = env.step(solver.act(None))
    assert float(base._dense_shaping(info)[0]) > float(far[0])
    set_state(env, angle=0.8)
    r_open = base.compute_dense_reward(None, None, base.evaluate())
    set_state(env, angle=0.3)
    r_half = base.compute_dense_reward(None, None, base.evaluate())
    assert float(r_half[0]) > float(r_open[0])


# Microwave poses at the corners of the documented ranges.
CORNERS = list(itertools.product(CloseMicrowaveEnv.CENTER_X_RANGE, CloseMicrowaveEnv.CENTER_Y_RANGE,
                                 CloseMicrowaveEnv.YAW_RANGE))


def _solve_from(env, seed, center, yaw, angle):
    env.reset(seed=seed)
    set_state(env, angle=angle, center=center, yaw=yaw)
    assert tcp_outside_swing(env)
    env.step(torch.zeros(env.action_space.shape))
    assert robot_microwave_contact(env) == 0.0, "the robot must start clear of the microwave"
    solver = make_solver(env)
    for _ in range(150):
        _, _, _, _, info = env.step(solver.act(None))
        if bool(info["success"][0]):
            return True
    return False


@pytest.mark.parametrize("angle", [LO_ANGLE, HI_ANGLE])
@pytest.mark.parametrize("corner", CORNERS)
def test_solver_reaches_every_corner(env, corner, angle):
    """Every corner of the pose box, door least and most open: starts clear, solver closes it (~5 s)."""
    x, y, yaw = corner
    assert _solve_from(env, 7, (x, y), yaw, angle)


def test_goal_box_holds_every_corner_pose(env):
    """The documented GOAL_BOX contains the closed free edge at every corner of the pose box."""
    base = env.unwrapped
    lo, hi = torch.tensor(base.GOAL_BOX_LOW), torch.tensor(base.GOAL_BOX_HIGH)
    env.reset(seed=8)
    for x, y, yaw in CORNERS + [(0.16, 0.32, 0.0)]:
        set_state(env, angle=0.8, center=(x, y), yaw=yaw)
        dg = base.evaluate()["desired_goal"][0]
        assert torch.all(dg >= lo) and torch.all(dg <= hi), f"desired goal {dg} outside the goal box"
