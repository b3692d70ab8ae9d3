"""Tests of the worker package on its own."""
