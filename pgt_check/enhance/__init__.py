"""enhance step."""
