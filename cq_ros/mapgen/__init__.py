"""Maps made rather than drawn: generated warehouses, and maps imported from the MovingAI benchmark format."""
