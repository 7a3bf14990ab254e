"""Instance labels of rendered frames: one integer per pixel saying what it shows.

=====================  ==============================================================
label                  what
=====================  ==============================================================
0                      background of the clean world (its painted ground and wall)
1                      the scanned primary branch
2 + i                  the scanned tree's secondary i (``TreeGT.secondaries[i]``)
2 + n                  the scanned tree's details, not scored (``TreeGT.details``:
                       spurs, stubs, buds), n = number of secondaries
3 + n                  the rest of the scanned tree, not scored: the other uprights and
                       the cordon of a UFO tree (orchard world)
100 + k                clutter object k of the clean world (``TreeGT.clutter``)
200                    sky (orchard world)
201                    ground (orchard world)
202                    trellis posts (orchard world)
203                    trellis wires, ties and clips (orchard world)
300                    the neighbouring trees of the row (orchard world)
301 + k                the k-th row behind (orchard world, impostors)
=====================  ==============================================================

Everything in ``[1, 100)`` is the scanned tree: the ground-truth mask of a segmenter.
"""

from __future__ import annotations

import numpy as np

BACKGROUND_LABEL = 0
PRIMARY_LABEL = 1
FIRST_SECONDARY_LABEL = 2
FIRST_CLUTTER_LABEL = 100
SKY_LABEL = 200
GROUND_LABEL = 201
POST_LABEL = 202
WIRE_LABEL = 203
FIRST_ROW_TREE_LABEL = 300

__all__ = [
    "BACKGROUND_LABEL",
    "FIRST_CLUTTER_LABEL",
    "FIRST_ROW_TREE_LABEL",
    "FIRST_SECONDARY_LABEL",
    "GROUND_LABEL",
    "PART_NAMES",
    "POST_LABEL",
    "PRIMARY_LABEL",
    "SKY_LABEL",
    "WIRE_LABEL",
    "details_label",
    "is_occluding_clutter",
    "is_scanned_tree",
    "label_parts",
    "own_uprights_label",
]

# What a pixel shows, in words (:func:`label_parts`): the scanned tree's parts first, then the
# rest of the scene.
PART_NAMES = (
    "primary",
    "side_branches",
    "details",
    "own_uprights",
    "background",
    "clutter",
    "sky",
    "ground",
    "posts",
    "wires",
    "row_neighbours",
    "back_rows",
    "other",
)


def details_label(n_secondaries: int) -> int:
    """The label of the scanned tree's unscored parts, after its ``n_secondaries`` secondaries."""
    return FIRST_SECONDARY_LABEL + n_secondaries


def own_uprights_label(n_secondaries: int) -> int:
    """The label of a UFO tree's other uprights and cordon (orchard world), after its details.

    Kept apart from :func:`details_label` because a segmenter's target may treat them apart:
    hand masks of real frames draw a tree's uprights but not its spurs or buds.
    """
    return details_label(n_secondaries) + 1


def is_scanned_tree(labels: np.ndarray) -> np.ndarray:
    """(same shape) bool: True where a label belongs to the scanned tree (``[1, 100)``)."""
    return (labels >= PRIMARY_LABEL) & (labels < FIRST_CLUTTER_LABEL)


def is_occluding_clutter(labels: np.ndarray) -> np.ndarray:
    """(same shape) bool: objects that are not the scanned tree but look like it to a segmenter.

    Clutter of the clean world, posts, wires and the row's trees; not the sky or the ground.
    """
    return (labels >= FIRST_CLUTTER_LABEL) & (labels != SKY_LABEL) & (labels != GROUND_LABEL)


def label_parts(labels: np.ndarray, n_secondaries: int) -> np.ndarray:
    """What each pixel shows, as an index into :data:`PART_NAMES`.

    Args:
        labels: (H, W) integer instance labels (module docstring).
        n_secondaries: The scanned tree's number of secondaries (places its details and
            uprights labels).

    Returns:
        (H, W) uint8 part index; labels outside the table read ``"other"``.

    Raises:
        ValueError: a negative label or secondary count.
    """
    labels = np.asarray(labels)
    if n_secondaries < 0:
        raise ValueError(f"n_secondaries must be >= 0, got {n_secondaries}")
    if labels.size and labels.min() < 0:
        raise ValueError(f"labels must be >= 0, got {labels.min()}")
    index = {name: k for k, name in enumerate(PART_NAMES)}
    top = max(int(labels.max()) if labels.size else 0, FIRST_ROW_TREE_LABEL + 1)
    table = np.full(top + 1, index["other"], np.uint8)
    table[BACKGROUND_LABEL] = index["background"]
    table[PRIMARY_LABEL] = index["primary"]
    details = details_label(n_secondaries)
    table[FIRST_SECONDARY_LABEL:details] = index["side_branches"]
    if details < FIRST_CLUTTER_LABEL:
        table[details] = index["details"]
    if details + 1 < FIRST_CLUTTER_LABEL:
        table[details + 1] = index["own_uprights"]
    table[FIRST_CLUTTER_LABEL:SKY_LABEL] = index["clutter"]
    table[SKY_LABEL] = index["sky"]
    table[GROUND_LABEL] = index["ground"]
    table[POST_LABEL] = index["posts"]
    table[WIRE_LABEL] = index["wires"]
    table[FIRST_ROW_TREE_LABEL] = index["row_neighbours"]
    table[FIRST_ROW_TREE_LABEL + 1 :] = index["back_rows"]
    return table[labels]
