"""A template third-party plugin for mocapflow."""
