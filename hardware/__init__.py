"""Arm adapters: the Kortex-style protocol and its backends."""
