"""``python -m lidarflow``: the ``lidarflow`` command."""

from lidarflow.cli import main

main()
