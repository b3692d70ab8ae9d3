"""Captures: one tree captured once, its manifest and its uploaded files."""
