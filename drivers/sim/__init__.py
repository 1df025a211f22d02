"""The plant driver: the same driver protocol, talking to an in-process plant."""
