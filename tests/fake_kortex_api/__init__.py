"""Test-only: a fake ``kortex_api`` (the ``kortex_api`` folder) and helpers to drive it (rig.py)."""
