"""Scenario files: loading and strict validation. Imports base and model/ only."""
