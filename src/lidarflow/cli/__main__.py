"""``python -m lidarflow.cli`` (as torchrun runs it)."""

from lidarflow.cli import main

main()
