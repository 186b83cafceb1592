"""What every hinge-closing task (CloseBox, CloseMicrowave) gets from maniskill_dualher.tasks.hinged.HingedPanelEnv and must show:
the per-episode desired-goal cache, one panel-pose read per step shared by goal, observation and reward, a
hinge that holds still unless pushed, a scripted push that closes it by contact, documented randomization,
and success exactly when the free edge's chord is within tolerance. Task-specific checks live in
tests/test_close_box.py and tests/test_close_microwave.py."""
import numpy as np
import pytest
import torch

import maniskill_dualher.tasks  # noqa: F401  (registers the tasks)
from maniskill_dualher.tasks.common import OBS_SLICES, split_goal_obs, transform_points
from maniskill_dualher.tasks.close_box import CloseBoxEnv
from maniskill_dualher.tasks.close_microwave import CloseMicrowaveEnv
from maniskill_dualher.tasks.hinged import HingedPanelEnv
from maniskill_dualher.tasks.solvers import make_solver

from articulated import goals_at_angle, make_env, robot_contact_force, set_state

HINGED = ["CloseBox-v1", "CloseMicrowave-v1"]


@pytest.fixture(scope="module", params=HINGED)
def env(request):
    e = make_env(request.param)
    assert isinstance(e.unwrapped, HingedPanelEnv)
    yield e
    e.close()


def test_cached_desired_goal_follows_the_body(env):
    """The desired goal is cached at reset; it must equal the closed free edge of the body where it stands."""
    base = env.unwrapped
    firsts = []
    for seed in (9, 10):
        obs, info = env.reset(seed=seed)
        first = info["desired_goal"].clone()
        for _ in range(5):
            obs, _, _, _, info = env.step(env.action_space.sample())
        assert torch.equal(info["desired_goal"], first), "the desired goal is constant within an episode"
        assert torch.equal(split_goal_obs(obs)[2], first)
        body = transform_points(base.articulation.pose.raw_pose, base._closed_free_edge_body)
        torch.testing.assert_close(first, body, atol=1e-6, rtol=0)
        firsts.append(first)
    assert not torch.equal(*firsts), "a new episode places the body elsewhere"


def test_goal_observation_and_info_read_the_same_step(env):
    base = env.unwrapped
    env.reset(seed=3)
    for _ in range(3):
        obs, _, _, _, info = env.step(env.action_space.sample())
        o, achieved, _ = split_goal_obs(obs)
        panel = base.panel.pose.raw_pose
        torch.testing.assert_close(o[:, OBS_SLICES["object_pose"]], panel, atol=0, rtol=0)
        torch.testing.assert_close(achieved, transform_points(panel, base._free_edge_local), atol=0, rtol=0)
        angle = base.articulation.qpos[:, 0]
        torch.testing.assert_close(info[base.ANGLE_INFO_KEY], angle, atol=0, rtol=0)
        torch.testing.assert_close(o[:, OBS_SLICES["joint_qpos"]][:, 0], angle, atol=0, rtol=0)


# --------------------------------------------------------------------------- physics and task definition
# What differs between the two tasks, for the shared tests below: the panel's hinge-to-edge length, angles
# at which the idle panel is checked, and the angles at which success is checked (one past each range).
SPEC = {
    "CloseBox-v1": dict(cls=CloseBoxEnv, length="LID_LENGTH", idle=(0.15,), success=(0.0, 0.03, 0.0995, 0.1005, 0.2, 0.7, 1.8)),
    "CloseMicrowave-v1": dict(cls=CloseMicrowaveEnv, length="DOOR_LENGTH", idle=(0.15, 1.5),
                              success=(0.0, 0.03, 0.0995, 0.1005, 0.2, 0.7, 1.55)),
}


def _cases(key):
    cases = []
    for task in HINGED:
        lo, hi = SPEC[task]["cls"].INIT_ANGLE_RANGE
        extra = (lo, hi) if key == "idle" else (hi,)
        cases += [(task, a) for a in (*extra, *SPEC[task][key])]
    return cases


def panel_length(base) -> float:
    return float(getattr(base, SPEC[base.spec.id]["length"]))


def angle(env) -> float:
    return float(env.unwrapped.articulation.qpos[0, 0])


def test_hinge_parameters_applied(env):
    base = env.unwrapped
    env.reset(seed=0)
    assert float(base.hinge.friction[0]) == pytest.approx(base.HINGE_FRICTION)  # set after build
    assert float(base.hinge.damping[0]) == pytest.approx(base.HINGE_DAMPING)
    torch.testing.assert_close(base.articulation.qlimits[0, 0],
                               torch.tensor(base.HINGE_LIMITS, dtype=torch.float32))
    assert base.goal_tolerance == pytest.approx(2 * panel_length(base) * np.sin(base.SUCCESS_ANGLE / 2))


@pytest.mark.parametrize("env,start", _cases("idle"), indirect=["env"])
def test_idle_panel_holds_its_angle(env, start):
    """Nothing touches the panel (robot holds its start pose): it must neither fall shut nor drift."""
    env.reset(seed=1)
    set_state(env, angle=start)
    zero = torch.zeros(env.action_space.shape)
    start = angle(env)
    for _ in range(100):
        _, _, _, _, info = env.step(zero)
        assert robot_contact_force(env, env.unwrapped.articulation) == 0.0, "the robot must start clear"
    assert abs(angle(env) - start) < 1e-3
    assert not bool(info["success"][0])


def test_solver_push_closes_panel_by_contact(env):
    """At the largest start angle the panel only moves while the robot touches it, and only shut."""
    base = env.unwrapped
    hi = base.INIT_ANGLE_RANGE[1]
    env.reset(seed=2)
    set_state(env, angle=hi)
    solver = make_solver(env)
    angles, touching = [angle(env)], []
    for _ in range(100):
        _, _, _, _, info = env.step(solver.act(None))
        angles.append(angle(env))
        touching.append(robot_contact_force(env, base.articulation) > 0.0)
        if bool(info["success"][0]):
            break
    angles = np.array(angles)
    assert bool(info["success"][0]) and angles[-1] < base.SUCCESS_ANGLE
    first_touch = touching.index(True)
    # Contacts are sampled at the end of each control step (5 sim steps); a first impact can end within
    # the step before, so allow the panel to start moving one step before the first sampled contact.
    assert np.all(np.abs(angles[:first_touch] - hi) < 1e-3), "the panel moved before the robot touched it"
    assert sum(touching) >= 3, "the panel is closed by sustained pushing, not one knock"
    assert np.all(np.diff(angles) < 1e-3), "the push must only close the panel"
    assert angles[0] - angles[-1] > 1.0


def test_panel_stays_closed_after_the_push(env):
    env.reset(seed=3)
    solver = make_solver(env)
    for _ in range(150):
        _, _, _, trunc, info = env.step(solver.act(None))
        if bool(trunc[0]):
            break
    assert bool(info["success"][0]), f"hinge angle {angle(env):.3f} at the end of the episode"
    assert angle(env) > -0.01, "the panel must not pass through its closed limit"


def test_randomization_in_documented_ranges(env):
    base = env.unwrapped
    doc = type(base).__doc__
    for lo, hi in (base.CENTER_X_RANGE, base.CENTER_Y_RANGE, base.YAW_RANGE, base.INIT_ANGLE_RANGE):
        assert f"[{lo:g}, {hi:g}]" in doc or f"[{lo:.2f}, {hi:.2f}]" in doc, f"range [{lo:g}, {hi:g}] is not documented"
    xs, ys, yaws, angles = [], [], [], []
    for seed in range(40):
        obs, info = env.reset(seed=seed)
        p, q = base.articulation.pose.p[0], base.articulation.pose.q[0]
        xs.append(float(p[0]))
        ys.append(float(p[1]))
        assert float(p[2]) == pytest.approx(base.BODY_LIFT, abs=1e-6), "the body stands on the table"
        assert abs(float(q[1])) < 1e-6 and abs(float(q[2])) < 1e-6, "the body only turns about z"
        yaws.append(2 * float(torch.atan2(q[3], q[0])))
        angles.append(angle(env))
        assert abs(float(base.articulation.qvel[0, 0])) < 1e-6, "the panel starts at rest"
        o = split_goal_obs(obs)[0][0]
        assert float(o[OBS_SLICES["joint_qpos"]][0]) == pytest.approx(angles[-1])
        torch.testing.assert_close(o[OBS_SLICES["object_pose"]], base.panel.pose.raw_pose[0])
    for vals, (lo, hi) in ((xs, base.CENTER_X_RANGE), (ys, base.CENTER_Y_RANGE), (yaws, base.YAW_RANGE),
                           (angles, base.INIT_ANGLE_RANGE)):
        vals = np.array(vals)
        assert vals.min() >= lo - 1e-5 and vals.max() <= hi + 1e-5
        assert vals.max() - vals.min() > 0.5 * (hi - lo), "the range should actually be used"


@pytest.mark.parametrize("env,hinge", _cases("success"), indirect=["env"])
def test_success_iff_free_edge_within_tolerance(env, hinge):
    base = env.unwrapped
    info, ag, dg = goals_at_angle(env, hinge)
    dist = float(torch.linalg.norm(ag - dg))
    assert dist == pytest.approx(2 * panel_length(base) * np.sin(hinge / 2), abs=2e-5)  # chord of the free edge
    assert bool(info["success"][0]) == (dist < base.goal_tolerance) == (hinge < base.SUCCESS_ANGLE)
    assert float(base.compute_reward(ag, dg)) == float(hinge < base.SUCCESS_ANGLE)
    assert float(info[base.ANGLE_INFO_KEY][0]) == pytest.approx(hinge, abs=1e-6)
