"""A fake of Kinova's ``kortex_api`` for the tests (see ../README.md); never installed."""
