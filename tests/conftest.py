pytest_plugins = ['temoto_core.testing.pytest_plugin']
