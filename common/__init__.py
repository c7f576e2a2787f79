"""Shared by every process: keys, messages, Zenoh configuration, the service base, auth."""
