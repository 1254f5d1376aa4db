"""Reproducible studies behind the research pages (docs/research/): each module runs as
``python -m studies.<name> --help``, writes its config and results as JSON into its output folder
(default ``runs/studies/<name>/``) and has a smoke test under ``tests/studies/``. Nothing under
``src/`` imports this package."""
