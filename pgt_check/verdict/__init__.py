"""verdict step."""
