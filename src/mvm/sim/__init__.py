"""Helpers of the simulator and its benchmark."""
