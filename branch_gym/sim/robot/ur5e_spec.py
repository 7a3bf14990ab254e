"""The UR5e's numbers: official DH table, joint and link names, joint limits, masses.

Pure data with sources, shared by the DH kinematics (``branch_gym/sim/robot/kinematics.py``) and the
URDF (``branch_gym/sim/robot/ur5e.py``), which are built from this one table.
"""

from __future__ import annotations

import math

import numpy as np

# Official UR5e DH parameters, Universal Robots "DH parameters for calculations of kinematics and
# dynamics" (support article; also reference.md "Costs measured"). Standard (distal) DH convention:
# T_{i-1,i} = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i). Lengths in metres, angles in radians.
DH_D_M = np.array([0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996])
DH_A_M = np.array([0.0, -0.425, -0.3922, 0.0, 0.0, 0.0])
DH_ALPHA_RAD = np.array([math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0])

N_JOINTS = 6
JOINT_NAMES = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
LINK_NAMES = (
    "shoulder_link",
    "upper_arm_link",
    "forearm_link",
    "wrist_1_link",
    "wrist_2_link",
    "wrist_3_link",
)
FLANGE_LINK = "flange"
CAMERA_LINK = "camera_optical"

# UR5e technical specifications (Universal Robots datasheet, "Joint ranges" and "Speed" rows):
# every joint +-360 deg; base, shoulder, elbow and the three wrists all 180 deg/s.
JOINT_LIMIT_RAD = 2.0 * math.pi
JOINT_SPEED_LIMIT_RADPS = np.full(N_JOINTS, math.radians(180.0))
# Rated joint torques (datasheet: size-3 joints 150 Nm, size-1 wrist joints 28 Nm); URDF needs them.
JOINT_EFFORT_NM = (150.0, 150.0, 150.0, 28.0, 28.0, 28.0)
# Link masses in kg from Universal Robots' published dynamics parameters (unused: kinematic sim).
LINK_MASS_KG = (3.761, 8.058, 2.846, 1.37, 1.3, 0.365)
BASE_MASS_KG = 4.0
