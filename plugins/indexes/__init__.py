"""Built-in indexes plugins."""
