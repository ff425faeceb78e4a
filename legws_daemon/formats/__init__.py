"""File formats: parsing, validation with one-line errors, and writing."""
