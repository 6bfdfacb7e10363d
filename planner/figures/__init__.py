"""Figures (matplotlib, Agg): a device's responses, a plan's report figures, designs, wafer maps."""
