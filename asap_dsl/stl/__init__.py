"""STL semantics."""
