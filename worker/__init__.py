"""The job runner that claims measurement jobs and calls canopy_core; built with its issue."""
