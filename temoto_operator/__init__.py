"""The operator's side of teleoperation: the hand (clutch, follower, drive), the dial, pointing, and the virtual hand.

It commands nothing itself: what it makes (servo targets, teleop streams, pointed goals) goes to the robot's motion
nodes, whose gates judge it. It imports only the core, so a station runs it without the Robot Manager."""
