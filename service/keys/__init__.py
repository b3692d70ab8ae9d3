"""API keys: prefixed random tokens with scopes, stored only as a hash."""
