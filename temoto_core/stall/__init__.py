"""Is a topic's publisher stalled, or is the machine only busy? One rule, for every consumer of a live stream.

- ``arrivals.py``: the silence limit from the stream's own rhythm;
- ``starvation.py``: how long the consumer's and the driver's threads waited for a CPU during a silence;
- ``detector.py``: ``TopicProbe`` (one watched topic) and ``StallDetector`` (the thread that calls a silence longer
  than its limit, plus the starvation measured in it, a stall).

The Sensor Manager watches the sensors it holds with it, and the Context Manager its trackers' inputs. It lived in
the Sensor Manager, and the Context Manager imported a sibling manager's internals to use it (issue 52).
"""
