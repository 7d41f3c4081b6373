"""The `formation` command line."""
