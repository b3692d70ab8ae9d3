"""The capture laptop's client: store-and-forward uploads of capture folders over flaky Wi-Fi.

Imports httpx, rich and the core's capture checks only (no FastAPI, no database, no Open3D), so
``canopy upload`` starts fast on a laptop.
"""
