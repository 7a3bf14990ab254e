"""The pybullet world: UR5e arm, procedural trees, eye-in-hand camera. Never imports recon."""
