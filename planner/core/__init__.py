"""Core types and helpers every layer uses: errors, units, impacter names, markdown tables, seeds, statistics."""
