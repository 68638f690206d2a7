"""REST routes of the inference service, one module per concern."""
