"""The ``plsgraph`` command: the only layer that parses arguments and prints."""
