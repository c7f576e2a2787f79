"""Both ends of a world: what the worlds (engine, bridge) and the code that drives
their robots (runner, ``wart control``) share: the world's interface, leases and
their MACs, and the remote robot link."""
