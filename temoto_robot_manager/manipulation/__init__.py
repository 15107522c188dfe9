"""The arms' manipulation: the manipulator node (goals and servoing through its command gate), kinematics and planning."""
