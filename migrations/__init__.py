"""Alembic migrations of the service's database; applied by ``canopy serve``/``canopy up`` on start."""
