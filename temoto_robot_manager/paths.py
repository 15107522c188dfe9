"""Where the Robot Manager's shipped files are (beside the package, in a checkout or after `pip install .`)."""
import os

DEFAULT_DESCRIPTION = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'config', 'vaultbot.yaml')
