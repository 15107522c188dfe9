"""Making a recorded bag safe to play: inputs that would act on a live stack get inert names.

A plain ``rosbag play`` publishes every topic under its recorded name. Played on a running stack,
the operator's instruction would start a graph, a cable message would unplug a device, and a
status could reach a registrar. So once the recorder has closed the bag, those topics are renamed
under ``/temoto_demo/recorded/`` (:func:`topics.inert_name`); everything else, the message data
and the timestamps are copied as they are. The report and ``temoto replay`` read them back.
"""
from __future__ import annotations

import os
from pathlib import Path

from rosbags.rosbag1 import Reader, Writer

from . import topics as T


def make_inert(bag_path: str, namespace: str = T.DEFAULT_NS) -> int:
    """Rename, in place, the topics of ``bag_path`` that would act on a live stack; returns how many.

    The new bag is written next to the old one and moved over it, so a crash leaves the original.
    """
    tmp = bag_path + '.inert.tmp'
    if os.path.exists(tmp):
        os.remove(tmp)
    renamed = set()
    with Reader(Path(bag_path)) as reader:
        # uncompressed: rosbags' LZ4 chunks are not read by ROS 1's player (ROSLZ4_DATA_ERROR), and BZ2
        # costs ~30 s for a demo bag; measured 14.6 MB uncompressed for one, against a 30 MB budget
        writer = Writer(Path(tmp))
        with writer:
            out = {}
            for conn in reader.connections:
                topic = conn.topic
                if T.acts_on_a_live_system(topic, namespace):
                    topic = T.inert_name(topic)
                    renamed.add(conn.topic)
                out[conn.id] = writer.add_connection(topic, conn.msgtype, msgdef=conn.msgdef.data,
                                                     md5sum=conn.digest, callerid=conn.ext.callerid,
                                                     latching=conn.ext.latching)
            for conn, stamp, raw in reader.messages():
                writer.write(out[conn.id], stamp, raw)
    os.replace(tmp, bag_path)
    return len(renamed)
