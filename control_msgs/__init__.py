"""control_msgs 1.5.2 (README.md): the Python package that holds its generated message modules."""
