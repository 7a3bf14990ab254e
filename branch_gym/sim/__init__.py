"""The pybullet world: UR5e arm, procedural trees, eye-in-hand camera.

Of ``recon`` it uses only pure helpers (field validation, tube frames); never the pipeline.
"""
