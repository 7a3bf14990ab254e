"""Point tracking over the tracking window (paper section IV-C).

The modeler asks a :class:`PointTracker` where the pixels it queried in the newest frame appear in
the M frames of the tracking window. Three implementations:

* :class:`LucasKanadeTracker`: OpenCV pyramidal Lucas-Kanade, chained from the newest frame to the
  oldest with a forward-backward check per step. RGB only, what a real robot runs.
* :class:`LearnedTrackerAdapter`: wraps a learned tracker (PIPs-class: M RGB images in, tracks and
  visibility out) behind the same interface.
* :class:`DepthOracleTracker`: exact tracks from the depth the frames carry (renderer or RGB-D),
  for ablations and fast training.

The package's public names, from where they live: the shared types :class:`Tracks` and
:class:`PointTracker` in ``recon/tracking/tracks.py``, the trackers in ``lucas_kanade.py``,
``recon/tracking/learned.py`` and ``recon/tracking/depth_oracle.py``; a tracker by name
(``lk``, ``oracle``) from :func:`make_tracker` in ``recon/tracking/factory.py``.
"""

from recon.tracking.depth_oracle import DepthOracleConfig, DepthOracleTracker
from recon.tracking.factory import TRACKERS, make_tracker
from recon.tracking.learned import LearnedTrackerAdapter, LearnedTrackFn
from recon.tracking.lucas_kanade import LucasKanadeConfig, LucasKanadeTracker
from recon.tracking.tracks import PointTracker, Tracks

__all__ = [
    "TRACKERS",
    "DepthOracleConfig",
    "DepthOracleTracker",
    "LearnedTrackFn",
    "LearnedTrackerAdapter",
    "LucasKanadeConfig",
    "LucasKanadeTracker",
    "PointTracker",
    "Tracks",
    "make_tracker",
]
