"""The paper's section 4 demonstration: sensor failover, recorded to a bag, with a report.

Modules, one idea each:
- ``topics``    the names the demo uses and records (one place, so record, run and report agree);
- ``relay``     a small node that reports every frame of the displayed sensor streams (a tick) and
                republishes them for the bag (scans and small clouds whole, the camera cloud decimated);
- ``recording`` the C++ bag recorder plus the relay, for ``temoto demo`` and ``temoto record``;
- ``bagfile``   renames a closed bag's inputs (instruction, cables, statuses) so a plain play is inert;
- ``replay``    ``temoto replay``: the recorded views shown again in RViz, on a master of its own;
- ``stack``     roscore and the nodes of ``launch/demo.launch``, one process group each,
                stopped in reverse order;
- ``scenario``  the stages: say, wait for a first frame, screenshot, unplug, ...;
- ``report``    the report computed from a bag alone (``rosbags``), with its timeline plot;
- ``cli``       ``temoto demo``, ``temoto record``, ``temoto report``.
"""
