"""YAML pipelines shipped with mocapflow (package data)."""
