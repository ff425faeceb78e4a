"""The ``legws`` command line."""
