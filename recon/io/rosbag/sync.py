"""Synchronisation: the masks and flow pictures of a bag matched to its images by stamp.

:class:`StampIndex` finds the message of a topic stamped nearest an image within a tolerance;
:class:`PendingFrames` holds the images until the mask and flow picture matched to them have been
read (the topics are interleaved in the bag: a mask may come before or after its image) and
hands them out in image order.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator

import numpy as np

from recon.io.folder import LoadedFrame


class StampIndex:
    """Stamps of a topic's messages (bag order), searchable by time.

    Args:
        stamps_ns: The messages' stamps (ns), in bag order.
    """

    def __init__(self, stamps_ns: list[int]) -> None:
        order = np.argsort(stamps_ns, kind="stable")
        self._sorted = np.asarray(stamps_ns, np.int64)[order]
        self._order = order

    def nearest(self, t_ns: int, tolerance_s: float) -> int | None:
        """Bag index of the message stamped nearest ``t_ns`` within ``tolerance_s``, or None."""
        stamps = self._sorted
        if len(stamps) == 0:
            return None
        i = int(np.searchsorted(stamps, t_ns))
        best = min(
            (j for j in (i - 1, i) if 0 <= j < len(stamps)), key=lambda j: abs(stamps[j] - t_ns)
        )
        if abs(int(stamps[best]) - t_ns) > round(tolerance_s * 1e9):
            return None
        return int(self._order[best])


class PendingFrames:
    """Images waiting for their mask and flow picture, handed out in image order.

    Each image waits with the bag indices (:class:`StampIndex`) of the mask and the flow picture
    it needs (-1: none) until both have been decoded; decoded messages that no waiting image
    needs are then forgotten.
    """

    def __init__(self) -> None:
        self.masks: dict[int, np.ndarray] = {}
        self.flows: dict[int, np.ndarray] = {}
        self._waiting: deque[tuple[LoadedFrame, int, int]] = deque()

    def wait(self, frame: LoadedFrame, mask: int, flow: int) -> None:
        """Queue an image frame needing mask ``mask`` and flow picture ``flow`` (-1: none)."""
        self._waiting.append((frame, mask, flow))

    def ready(self) -> Iterator[LoadedFrame]:
        """The waiting frames, oldest first, up to the first whose messages are still unread."""
        while self._waiting and self._arrived(self._waiting[0]):
            frame, mask, flow = self._waiting.popleft()
            if mask >= 0:
                frame.mask = self.masks[mask]
            if flow >= 0:
                frame.flow_image = self.flows[flow]
            yield frame
            # drop what no waiting image needs (stamps increase)
            _drop_used(self.masks, mask, {m for _, m, _ in self._waiting})
            _drop_used(self.flows, flow, {f for _, _, f in self._waiting})

    def rest(self, mask_topic: str | None) -> Iterator[LoadedFrame]:
        """The frames still waiting at the end of the bag: a mask that never came skips its
        frame; a flow picture that never came leaves it without one."""
        for frame, mask, flow in self._waiting:
            if mask >= 0 and mask not in self.masks:
                reason = f"mask {mask} on {mask_topic!r} missing from the bag"
                yield frame.skip("no mask", reason)
                continue
            if mask >= 0:
                frame.mask = self.masks[mask]
            frame.flow_image = self.flows.get(flow)
            yield frame
        self._waiting.clear()

    def _arrived(self, entry: tuple[LoadedFrame, int, int]) -> bool:
        """Whether a waiting image's mask and flow picture have been read."""
        _, mask, flow = entry
        return (mask < 0 or mask in self.masks) and (flow < 0 or flow in self.flows)


def _drop_used(decoded: dict[int, np.ndarray], used: int, still_needed: set[int]) -> None:
    """Forget the decoded messages up to ``used`` that no waiting image needs."""
    if used < 0:
        return
    for m in [m for m in decoded if m <= used and m not in still_needed]:
        del decoded[m]
