"""CloseMicrowave-v1 specifics (what both hinge tasks must show is in tests/test_hinged.py; the shared task
contract in tests/test_tasks.py)."""
import itertools

import numpy as np
import pytest
import torch

import maniskill_dualher.tasks  # noqa: F401  (registers the tasks)
from mani_skill.utils.geometry import rotation_conversions as rc
from maniskill_dualher.tasks.close_microwave import CloseMicrowaveEnv
from maniskill_dualher.tasks.solvers import make_solver

from articulated import env_fixture, goals_at_angle, robot_contact_force, set_state

LO_ANGLE, HI_ANGLE = CloseMicrowaveEnv.INIT_ANGLE_RANGE


env = env_fixture("CloseMicrowave-v1")


def door_angle(env) -> float:
    return float(env.unwrapped.microwave.qpos[0, 0])


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


@pytest.mark.parametrize("angle", [0.03, 0.7, HI_ANGLE])
def test_free_edge_swings_horizontally_towards_the_robot(env, angle):
    """Vertical hinge: the free edge moves in the horizontal plane, towards the robot (-x in the body frame)."""
    base = env.unwrapped
    _, ag, dg = goals_at_angle(env, angle)
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
