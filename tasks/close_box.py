"""CloseBox-v1: push shut the lid of an open box standing on the table in front of the Panda."""
from __future__ import annotations

import numpy as np
import sapien

from mani_skill.utils.registration import register_env

from .common import DEFAULT_MAX_EPISODE_STEPS
from .hinged import HingedGeometry, HingedPanelEnv, chord_tolerance

# x-axis -> -y: a joint frame with this rotation turns about the world -y axis (joint axis = frame
# x-axis), so a positive hinge angle lifts the lid's free (+x) edge up.
_Q_X_TO_MINUS_Y = [float(np.sqrt(0.5)), 0.0, 0.0, -float(np.sqrt(0.5))]


@register_env("CloseBox-v1", max_episode_steps=DEFAULT_MAX_EPISODE_STEPS)
class CloseBoxEnv(HingedPanelEnv):
    """
    **Task Description:**
    Close the lid of a box standing on the table in front of the Panda. The box is an open-top shell
    (bottom and four walls) built from primitive collision boxes, 0.14 m deep (x) x 0.20 m wide (y) x
    0.09 m tall, fixed to the table. Its lid (0.14 x 0.20 m, 1 cm thick) turns on a horizontal revolute
    hinge along the box's top edge nearer the robot (the -x edge in the box frame); the hinge angle is
    0 when closed and grows as the free (far) edge rises and swings towards the robot (limits
    [0, 1.9] rad). Opened, the lid stands on the robot's side of the box with its outer face towards
    the robot, so the Panda closes it by pushing that face forward and down; the resting TCP (near
    (0, 0, 0.17)) lies in front of the hinge, outside the lid's swing, at every initial angle and pose.

    The lid is counterbalanced (its centre of mass sits 1.5 cm from the hinge axis, as with a
    spring-balanced lid stay) and the hinge has friction 0.5 and damping 0.2 N m s/rad: it holds any
    angle when nothing touches it (measured drift < 1e-6 rad over 100 idle steps at 0.02 to 1.85 rad)
    and a push of a few newtons closes it (the scripted solver sweeps it shut at ~2 rad/s with a
    ~16 N contact force). (A uniform lid, centre of mass half-way out, still creeps shut with
    PhysX joint friction 2.5, ~1e-2 rad per 100 steps near closed, and that friction makes it several
    times stiffer to push; hence the counterweight.)

    **Randomizations:**
    - the box body's centre is placed uniformly in x in [0.13, 0.16], y in [-0.10, 0.10] (metres, world
      frame; table top at z = 0, robot base at x = -0.615), on the table
    - its yaw is uniform in [-0.1, 0.1] rad (0 = hinge edge facing the robot, i.e. facing -x)
    - the lid's initial angle is uniform in [0.5, 1.3] rad open, at rest
    - the robot's joints get the usual ManiSkill Gaussian noise (``robot_init_qpos_noise``, 0.02 rad)
    - hence the desired goal lies in ``GOAL_BOX_LOW``..``GOAL_BOX_HIGH`` = x in [0.195, 0.235],
      y in [-0.11, 0.11], z in [0.09, 0.10]

    **Success Conditions:**
    - the lid angle is below 0.1 rad. Equivalently (and this is how it is evaluated): the achieved goal,
      the midpoint of the lid's free edge on its inner (lower) face (3-D, world frame; at L = 0.14 m from
      the hinge axis), lies within ``goal_tolerance = 2 L sin(0.05) ~= 0.0140 m`` of the desired goal,
      the same point with the lid closed. The chord between the two positions of the point is
      2 L sin(angle / 2), so "distance < tolerance" is exactly "angle < 0.1".

    **Observation slots** (see ``maniskill_dualher.tasks.common``): task object pose = the lid link's pose, task joint =
    hinge angle and angular velocity, no distractors.

    **Dense reward:** the common goal term ``1 - tanh(5 * goal_distance)`` plus a reaching term
    ``0.5 * (1 - tanh(10 * ||tcp - push_point||))`` towards the push point, the middle of the lid's outer
    face (``PUSH_RADIUS`` from the hinge); 2.0 on success.
    """

    # Box (shell) dimensions, metres.
    BOX_DEPTH = 0.14  # x, away from the robot
    BOX_WIDTH = 0.20  # y
    BOX_HEIGHT = 0.09  # z
    WALL = 0.008
    BOX_LIFT = BODY_LIFT = 0.001  # above the table
    # Lid.
    LID_THICKNESS = 0.01
    LID_GAP = 0.002  # between the top of the walls and the closed lid's inner face
    LID_LENGTH = BOX_DEPTH  # hinge axis to free edge
    LID_DENSITY = 500.0
    LID_COM_OFFSET = 0.015  # centre of mass from the hinge axis along the lid (counterbalanced)
    HINGE_DAMPING = 0.2
    HINGE_FRICTION = 0.5
    HINGE_LIMITS = (0.0, 1.9)
    PUSH_RADIUS = 0.08  # push point on the outer face, distance from the hinge axis

    # Randomization ranges (documented in the class docstring; tests check them).
    CENTER_X_RANGE = (0.13, 0.16)
    CENTER_Y_RANGE = (-0.10, 0.10)
    YAW_RANGE = (-0.1, 0.1)
    INIT_ANGLE_RANGE = (0.5, 1.3)
    SUCCESS_ANGLE = 0.1
    # Every desired goal (closed free-edge midpoint, 0.07 m ahead of the box centre at z = 0.093) lies in
    # this box: x in [0.13 + 0.07 cos 0.1, 0.16 + 0.07], |y| <= 0.10 + 0.07 sin 0.1, z = 0.093.
    GOAL_BOX_LOW = (0.195, -0.11, 0.09)
    GOAL_BOX_HIGH = (0.235, 0.11, 0.10)

    ANGLE_INFO_KEY = "lid_angle"
    goal_tolerance = chord_tolerance(LID_LENGTH, SUCCESS_ANGLE)
    success_text = f"the box lid closed to within {SUCCESS_ANGLE:g} rad"

    def _geometry(self) -> HingedGeometry:
        hx, hy, h = self.BOX_DEPTH / 2, self.BOX_WIDTH / 2, self.BOX_HEIGHT
        t, L, th = self.WALL, self.LID_LENGTH, self.LID_THICKNESS
        mass = self.LID_DENSITY * L * self.BOX_WIDTH * th
        inertia = mass / 12 * np.array([self.BOX_WIDTH ** 2 + th ** 2, L ** 2 + th ** 2, L ** 2 + self.BOX_WIDTH ** 2])
        return HingedGeometry(
            name="box", body_name="box", panel_name="lid", joint_name="lid_hinge",
            # box frame (origin: bottom centre): bottom, -x, +x, -y, +y walls
            body_parts=[
                ([0, 0, t / 2], [hx, hy, t / 2]),
                ([-hx + t / 2, 0, h / 2], [t / 2, hy, h / 2]),
                ([hx - t / 2, 0, h / 2], [t / 2, hy, h / 2]),
                ([0, -hy + t / 2, h / 2], [hx - t, t / 2, h / 2]),
                ([0, hy - t / 2, h / 2], [hx - t, t / 2, h / 2]),
            ],
            # lid frame: origin on the hinge axis at the lid's inner face; closed, the lid runs along +x
            # with its inner face at z = 0 and its outer face at z = +thickness
            panel_parts=[([L / 2, 0, th / 2], [L / 2, hy, th / 2])],
            panel_density=self.LID_DENSITY,
            panel_mass_inertia=(mass, sapien.Pose([self.LID_COM_OFFSET, 0, th / 2]), inertia),
            hinge_in_body=sapien.Pose([-hx, 0, h + self.LID_GAP], _Q_X_TO_MINUS_Y),
            hinge_in_panel=sapien.Pose([0, 0, 0], _Q_X_TO_MINUS_Y),
            free_edge_panel=[L, 0.0, 0.0],
            push_panel=[self.PUSH_RADIUS, 0.0, th],
            closed_free_edge_body=[-hx + L, 0.0, h + self.LID_GAP],
            body_color=[0.55, 0.38, 0.22, 1.0],
            panel_color=[0.70, 0.50, 0.30, 1.0],
            parked_pose=sapien.Pose(p=[0.5, 0.6, self.BOX_LIFT]),  # clear of the robot until reset
        )

    @property
    def box(self):
        return self.articulation

    @property
    def lid(self):
        return self.panel
