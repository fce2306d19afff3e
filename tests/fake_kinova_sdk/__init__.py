"""The fake Kinova Gen2 SDK for the tests (fake_kinova.c) and its Python driver (fake.py)."""
