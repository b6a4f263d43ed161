"""Processes and transports of a distributed run: peers exchanging halos (Zenoh, or in-process for
tests), and the viewer."""
