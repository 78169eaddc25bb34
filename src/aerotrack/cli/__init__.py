"""The command-line layer: thin click commands over library functions. Logging is configured here only."""
