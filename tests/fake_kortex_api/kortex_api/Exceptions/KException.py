class KException(Exception):
    """Base of the vendor's exceptions."""
