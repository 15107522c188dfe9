"""The Context Manager on the wire: its two registrars, their servers and service types.

Trackers live in a registrar of their own (``TRACKER_RR_NAME``), so that
``track_object``, which loads a tracker, calls another registrar and not itself.
Its server and every client (``interface.py``) import this module, never each
other. Both use the default equality: every field but the ``trr`` header.
"""
from temoto_context_manager.srv import LoadTracker, TrackObject
from temoto_core.rr.deadlines import register_deadlines

RR_NAME = 'temoto_context_manager'
TRACKER_RR_NAME = 'temoto_context_manager_trackers'
LOAD_TRACKER = 'load_tracker'
LOAD_TRACKER_TYPE = LoadTracker
TRACK_OBJECT = 'track_object'
TRACK_OBJECT_TYPE = TrackObject

# The longest a load may take (deadlines.py): a tracker starts its sensors and waits for its first data
# (15 s by default); tracking an object loads a tracker.
register_deadlines(LoadTracker._request_class, load=60.0, unload=20.0)
register_deadlines(TrackObject._request_class, load=70.0, unload=25.0)
