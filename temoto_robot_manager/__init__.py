"""TeMoto Robot Manager: robots, their features, and motion that stops when what it depends on is gone."""
