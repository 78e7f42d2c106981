"""Built-in cleaners plugins."""
