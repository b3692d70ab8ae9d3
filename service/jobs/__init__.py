"""Measurement jobs: the queue the API fills and workers drain, with leases and retries."""
