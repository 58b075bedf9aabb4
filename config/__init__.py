"""The shipped configuration files, installed as the package data ``companion.configs`` (see pyproject.toml)."""
