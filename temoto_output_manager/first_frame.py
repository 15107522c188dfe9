"""When has a display drawn data from its topic? ("first frame drawn")

This is where a failover timing ends, so it must never fire early. The signal
comes from RViz itself, not from a side subscriber: a display's status line
("Topic: N messages received", "Image: N images received") counts messages
that passed RViz's TF message filter, i.e. data the display can actually draw.
That count is set when the message is handed to the display (for PointCloud2
in RViz's threaded queue); the geometry reaches the screen in the next
VisualizationManager::onUpdate, which renders synchronously and increments
the frame counter. The host samples (frame count, message count) from the Qt
main thread, where onUpdate also runs, so:

- first sample with a message seen, at frame count c  →  drawn once the frame
  count exceeds c. The report is never early and at most one frame period
  plus one sampling period late.
- displays without a topic (robot model, TF, grid) are "drawn" at the first
  frame rendered after they were added.
- classes whose status has no message count (Marker, MarkerArray, DepthCloud,
  InteractiveMarkers) fall back to a probe subscriber in the host: RViz queues
  such messages and handles them in the next onUpdate, so the watch waits for
  one more frame than with a count (``margin=1``).
"""
from __future__ import annotations

import re
from typing import Optional

_RECEIVED = re.compile(r'^\s*(\d+)\s+(?:messages|images)\s+received')


def received_count(status_text: str) -> Optional[int]:
    """'12 messages received' → 12; anything else → None."""
    m = _RECEIVED.match(status_text or '')
    return int(m.group(1)) if m else None


class FirstFrameWatch:
    """State of one display on its way to its first drawn frame."""

    def __init__(self, needs_data: bool, frame_count: int, margin: int = 0):
        self.needs_data = needs_data
        self.margin = margin
        # frame count at the sample where data was first seen; for topic-less displays: at add time
        self.data_frame: Optional[int] = None if needs_data else frame_count
        self.drawn_frame: Optional[int] = None

    @property
    def drawn(self) -> bool:
        return self.drawn_frame is not None

    def observe(self, frame_count: int, messages: Optional[int]) -> bool:
        """Feed one sample; True exactly once, when the first frame with data is on screen."""
        if self.drawn:
            return False
        if self.data_frame is None:
            if messages:
                self.data_frame = frame_count
            return False
        if frame_count > self.data_frame + self.margin:
            self.drawn_frame = frame_count
            return True
        return False

    def restart(self, frame_count: int, holding: bool = False) -> None:
        """The topic changed: wait for data from the new one. ``holding``: a hidden display shown again that holds
        data already: it is on screen at the next frame, with no new message to wait for."""
        self.data_frame = frame_count if holding or not self.needs_data else None
        self.drawn_frame = None
