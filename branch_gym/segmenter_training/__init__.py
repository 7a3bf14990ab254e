"""Data generation and training of the learned branch segmenter (uses the simulator).

The network, its weights format and its loading live in :mod:`recon.segmentation` (no
simulator there); this package renders training frames (:mod:`.generate`), randomises them in
image space (:mod:`.augment`), trains (:mod:`.train`) and measures IoU on unseen trees
(:mod:`.evaluate`). CLI: ``python -m branch_gym.segmenter_training --help``.
"""
