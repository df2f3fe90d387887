"""Data pipelines over the env: evaluation of policies."""
