"""Simulation core: field constants, PyBullet world, chassis model, referee, spawns."""
