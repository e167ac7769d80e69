"""Serving arenas over Zenoh: the transport-free service, the Zenoh loop, the
``neuronsmae-server`` command, and the fleet supervisor behind ``neuronsmae-fleet``."""
