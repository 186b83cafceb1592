"""CloseMicrowave-v1: push a microwave's side-hinged door shut (the paper's target task)."""
from __future__ import annotations

import numpy as np
import sapien

from mani_skill.utils.registration import register_env

from .common import DEFAULT_MAX_EPISODE_STEPS
from .hinged import HingedGeometry, HingedPanelEnv, chord_tolerance

# x-axis -> +z: a joint frame with this rotation turns about the vertical (joint axis = frame x-axis).
_Q_X_TO_Z = [float(np.sqrt(0.5)), 0.0, -float(np.sqrt(0.5)), 0.0]


@register_env("CloseMicrowave-v1", max_episode_steps=DEFAULT_MAX_EPISODE_STEPS)
class CloseMicrowaveEnv(HingedPanelEnv):
    """
    **Task Description:**
    Close the door of a microwave standing on the table in front of the Panda, to its left (+y). The
    microwave is a box shell (bottom, top, back and two side walls; the front facing the robot is open)
    built from primitive collision boxes, 0.26 m deep (x) x 0.30 m wide (y) x 0.18 m tall, fixed to the
    table. Its door (0.30 m wide, 0.166 m tall, 1.5 cm thick, with a handle bar near its free edge on the
    outer face) turns on a vertical revolute hinge at the front corner nearer the robot's centre line
    (-y side), on the door's outer face. The hinge angle is 0 when closed and grows as the free edge
    swings towards the robot (limits [0, pi/2]). The door is lifted 1 cm above the table and its hinge
    has damping 1.0 N m s/rad and friction 0.1 N m (a vertical hinge feels no gravity torque): it holds
    its angle when nothing touches it (drift 0 over 100 idle steps, measured at 0.15-1.5 rad) and does
    not bounce at the closed limit; 0.1 N m (0.33 N at the free edge) breaks it loose and closing it at
    1 rad/s takes 1.1 N m (about 4 N at the free edge, 7 N at the middle).

    The microwave stands to the side (hinge at y >= 0.11) so that the resting hand (TCP near
    (0, 0, 0.17), open fingers) is never between the door and the body: at every initial angle and pose
    the TCP is beside the hinge or on the door's outer side, and the hand starts clear of the microwave
    (the body is low enough, 0.18 m, that the resting palm passes over the door).

    **Randomizations:**
    - the microwave body's centre is placed uniformly in x in [0.12, 0.2], y in [0.29, 0.35] (metres,
      world frame; table top at z = 0, robot base at x = -0.615), standing on the table (1 mm above it)
    - its yaw is uniform in [-0.15, 0.15] rad (0 = opening facing the robot, i.e. facing -x)
    - the door's initial angle is uniform in [0.4, 1.2] rad open, at rest
    - the robot's joints get the usual ManiSkill Gaussian noise (``robot_init_qpos_noise``, 0.02 rad)
    - hence the desired goal lies in ``GOAL_BOX_LOW``..``GOAL_BOX_HIGH`` = x in [-0.05, 0.08],
      y in [0.41, 0.53], z in [0.09, 0.10]

    **Success Conditions:**
    - the door angle is below 0.1 rad. Equivalently (and this is how it is evaluated): the achieved
      goal, the midpoint of the door's free edge on its outer face (3-D, world frame; at radius
      L = 0.30 m from the hinge axis), lies within ``goal_tolerance = 2 L sin(0.05) ~= 0.0300 m`` of
      the desired goal, the same point with the door closed. The chord between the two positions of
      the point is 2 L sin(angle / 2), so "distance < tolerance" is exactly "angle < 0.1".

    **Observation slots** (see ``maniskill_dualher.tasks.common``): task object pose = the door link's pose (origin on the
    hinge axis; the body pose follows from it and the angle), task joint = hinge angle and angular
    velocity, no distractors.

    **Dense reward:** the common goal term ``1 - tanh(5 * goal_distance)`` plus a reaching term
    ``0.5 * (1 - tanh(10 * ||tcp - push_point||))`` towards the push point, the middle of the door's outer
    face (``PUSH_RADIUS`` from the hinge); 2.0 on success.
    """

    # Body (shell) dimensions, metres.
    BODY_DEPTH = 0.26  # x, away from the robot
    BODY_WIDTH = 0.30  # y
    BODY_HEIGHT = 0.18  # z
    WALL = 0.01
    BODY_LIFT = 0.001  # above the table: a body resting on the table adds contact pairs to every step
    # Door.
    DOOR_THICKNESS = 0.015
    DOOR_GAP = 0.004  # between the closed door's inner face and the shell's front edges
    DOOR_LIFT = 0.01  # above the table (a door resting on the table rubs)
    DOOR_LENGTH = BODY_WIDTH  # hinge axis to free edge
    DOOR_HEIGHT = BODY_HEIGHT - DOOR_LIFT - 0.004
    HINGE_DAMPING = 1.0
    HINGE_FRICTION = 0.1
    HINGE_LIMITS = (0.0, float(np.pi / 2))
    # Handle bar on the outer face near the free edge (door frame: x = 0 is the outer face).
    HANDLE_HALF_SIZE = (0.0125, 0.0075, 0.05)
    HANDLE_INSET = 0.03  # handle centre, from the free edge
    PUSH_RADIUS = DOOR_LENGTH / 2  # push point: middle of the outer face, this far from the hinge axis

    # Randomization ranges (documented in the class docstring; tests check them).
    CENTER_X_RANGE = (0.12, 0.20)
    CENTER_Y_RANGE = (0.29, 0.35)
    YAW_RANGE = (-0.15, 0.15)
    INIT_ANGLE_RANGE = (0.4, 1.2)
    SUCCESS_ANGLE = 0.1
    # Every desired goal (closed free-edge midpoint, at (a, b, z) = (-0.149, +0.15, 0.093) in the body
    # frame) lies in this box: x = cx + a cos(yaw) - b sin(yaw) in [0.12 - 0.170, 0.20 - 0.125],
    # y = cy + a sin(yaw) + b cos(yaw) in [0.29 + 0.126, 0.35 + 0.171], z = 0.093.
    GOAL_BOX_LOW = (-0.05, 0.41, 0.09)
    GOAL_BOX_HIGH = (0.08, 0.53, 0.10)

    ANGLE_INFO_KEY = "door_angle"
    goal_tolerance = chord_tolerance(DOOR_LENGTH, SUCCESS_ANGLE)
    success_text = f"the microwave door closed to within {SUCCESS_ANGLE:g} rad"

    def _geometry(self) -> HingedGeometry:
        hx, hy, hz = self.BODY_DEPTH / 2, self.BODY_WIDTH / 2, self.BODY_HEIGHT / 2
        t, L, th, hd = self.WALL, self.DOOR_LENGTH, self.DOOR_THICKNESS, self.DOOR_HEIGHT
        return HingedGeometry(
            name="microwave", body_name="body", panel_name="door", joint_name="door_hinge",
            # body frame (origin: bottom centre): bottom, top, back, -y side, +y side; the front is open
            body_parts=[
                ([0, 0, t / 2], [hx, hy, t / 2]),
                ([0, 0, self.BODY_HEIGHT - t / 2], [hx, hy, t / 2]),
                ([hx - t / 2, 0, hz], [t / 2, hy, hz]),
                ([0, -hy + t / 2, hz], [hx, t / 2, hz]),
                ([0, hy - t / 2, hz], [hx, t / 2, hz]),
            ],
            # door frame: origin on the hinge axis, at the bottom of the door's outer face (the hinge sits
            # at the outer corner, so the opened door stays on the +y side of its hinge); closed, the door
            # runs along +y, its outer face (towards the robot) at x = 0 and its inner face at x = +thickness
            panel_parts=[
                ([th / 2, L / 2, hd / 2], [th / 2, L / 2, hd / 2]),
                ([-self.HANDLE_HALF_SIZE[0], L - self.HANDLE_INSET, hd / 2], list(self.HANDLE_HALF_SIZE)),
            ],
            hinge_in_body=sapien.Pose([-hx - self.DOOR_GAP - th, -hy, self.DOOR_LIFT], _Q_X_TO_Z),
            hinge_in_panel=sapien.Pose([0, 0, 0], _Q_X_TO_Z),
            free_edge_panel=[0.0, L, hd / 2],
            push_panel=[0.0, self.PUSH_RADIUS, hd / 2],
            closed_free_edge_body=[-hx - self.DOOR_GAP - th, -hy + L, self.DOOR_LIFT + hd / 2],
            body_color=[0.75, 0.75, 0.78, 1.0],
            panel_color=[0.15, 0.15, 0.18, 1.0],
            parked_pose=sapien.Pose(p=[0.5, 0.6, 0]),  # clear of the robot until reset places it
        )

    @property
    def microwave(self):
        return self.articulation

    @property
    def door(self):
        return self.panel
