"""TeMoto action engine.

Actions are plugins: a folder holding ``<name>.umrf.json`` (the descriptor) and a
Python module with a class derived from :class:`temoto_action_engine.action_base.ActionBase`.
The engine indexes such folders, grounds natural-language instructions into UMRF
graphs, and runs the graphs; every action instance owns a Resource Registrar so
that whatever it requested is released when it ends.
"""
