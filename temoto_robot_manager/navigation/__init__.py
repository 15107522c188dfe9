"""The base's navigation: the navigator node, its goal logic (plan, follow, monitor), and its command gate's inputs."""
