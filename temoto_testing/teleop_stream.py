#!/usr/bin/env python3
"""A teleop stream on ``teleop/cmd_vel``, as a station sends one: 50 Hz of a turn in place, stamped on time, then
stamped ``HOLD`` s in the past (as a link that held the stream and delivers it now), then silent. Run it under
``faketime`` for a station whose clock is skewed.
Usage: python -m temoto_testing.teleop_stream ON_S LATE_S HOLD_S [ANGULAR]. Prints 'phase on', 'phase late' and
'done' as it goes, and each ``teleop/status`` it hears as 'status <text>'."""
import sys

import rospy
from geometry_msgs.msg import TwistStamped
from std_msgs.msg import String

RATE_HZ = 50.0


def _say(line: str) -> None:
    sys.stdout.write(line + '\n')
    sys.stdout.flush()


def main() -> None:
    on_s, late_s, hold_s = (float(v) for v in sys.argv[1:4])
    angular = float(sys.argv[4]) if len(sys.argv) > 4 else 0.5
    rospy.init_node('teleop_stream', anonymous=True)
    pub = rospy.Publisher('/teleop/cmd_vel', TwistStamped, queue_size=5, tcp_nodelay=True)
    rospy.Subscriber('/teleop/status', String, lambda m: _say('status %s' % m.data), queue_size=50)
    rate = rospy.Rate(RATE_HZ)
    for _ in range(int(30 * RATE_HZ)):                 # the navigator listening, within 30 s
        if pub.get_num_connections() > 0:
            break
        rate.sleep()
    for phase, seconds, age in (('on', on_s, 0.0), ('late', late_s, hold_s)):
        _say('phase %s' % phase)
        for _ in range(int(seconds * RATE_HZ)):
            msg = TwistStamped()
            msg.header.stamp = rospy.Time.from_sec(rospy.get_time() - age)
            msg.twist.angular.z = angular
            pub.publish(msg)
            rate.sleep()
    _say('done')
    rospy.spin()


if __name__ == '__main__':
    main()
