"""The paper's section 4 demonstration: sensor failover, recorded to a bag, with a report.

Modules, one idea each:
- ``topics``    the names the demo uses and records (one place, so record, run and report agree);
- ``relay``     a small node that reports every frame of the displayed sensor streams (a tick) and
                republishes them throttled, so the bag stays small but the timing stays exact;
- ``recording`` the C++ bag recorder plus the relay, for ``temoto demo`` and ``temoto record``;
- ``stack``     roscore and the nodes of ``launch/demo.launch``, one process group each,
                stopped in reverse order;
- ``scenario``  the stages: say, wait for a first frame, screenshot, unplug, ...;
- ``report``    the report computed from a bag alone (``rosbags``), with its timeline plot;
- ``cli``       ``temoto demo``, ``temoto record``, ``temoto report``.
"""
