"""Procedural trees with exact ground truth: distribution (config), generator, ground truth."""
