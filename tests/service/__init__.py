"""Tests of the measurement service and its worker, over HTTP against real processes."""
