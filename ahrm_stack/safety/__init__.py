"""The QP safety filter (spec §5)."""
