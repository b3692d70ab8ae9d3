"""The measurement service (HTTP API and system of record); built with its issue."""
