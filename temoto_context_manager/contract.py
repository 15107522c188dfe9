"""The Context Manager on the wire: its two registrars, their servers and service types.

Trackers live in a registrar of their own (``TRACKER_RR_NAME``), so that
``track_object``, which loads a tracker, calls another registrar and not itself.
Its server and every client (``interface.py``) import this module, never each
other. Both use the default equality: every field but the ``trr`` header.
"""
from temoto_context_manager.srv import LoadTracker, TrackObject

RR_NAME = 'temoto_context_manager'
TRACKER_RR_NAME = 'temoto_context_manager_trackers'
LOAD_TRACKER = 'load_tracker'
LOAD_TRACKER_TYPE = LoadTracker
TRACK_OBJECT = 'track_object'
TRACK_OBJECT_TYPE = TrackObject
