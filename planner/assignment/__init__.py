"""Frequency assignment: channels for every impacter (colouring), re-assignment, placement."""
