"""Transport: zenoh sessions and keys."""
