"""Point tracking over the tracking window (paper section IV-C).

The modeler asks a :class:`PointTracker` where the pixels it queried in the newest frame appear in
the M frames of the tracking window. Three implementations:

* :class:`LucasKanadeTracker`: OpenCV pyramidal Lucas-Kanade, chained from the newest frame to the
  oldest with a forward-backward check per step. RGB only, what a real robot runs.
* :class:`LearnedTrackerAdapter`: wraps a learned tracker (PIPs-class: M RGB images in, tracks and
  visibility out) behind the same interface.
* :class:`DepthOracleTracker`: exact tracks from the depth the frames carry (renderer or RGB-D),
  for ablations and fast training.

Where they live (all re-exported here): the shared types :class:`Tracks` and
:class:`PointTracker` in ``recon/tracks.py``, the trackers in ``recon/lk_tracker.py``,
``recon/learned_tracker.py`` and ``recon/depth_oracle.py``.
"""

from recon.depth_oracle import DepthOracleConfig, DepthOracleTracker
from recon.learned_tracker import LearnedTrackerAdapter, LearnedTrackFn
from recon.lk_tracker import LucasKanadeConfig, LucasKanadeTracker
from recon.tracks import PointTracker, Tracks

__all__ = [
    "DepthOracleConfig",
    "DepthOracleTracker",
    "LearnedTrackFn",
    "LearnedTrackerAdapter",
    "LucasKanadeConfig",
    "LucasKanadeTracker",
    "PointTracker",
    "Tracks",
]
