"""The UR5e with its eye-in-hand camera: model (URDF), kinematics, motion, IK, home pose."""
